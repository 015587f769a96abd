/*
 * The native plant's model at a state, shared by its translation units: the state sizes, the model at one state
 * (Eval), the plant's data (PlantData) and the functions that evaluate it (plant.c); the integration schemes
 * are in plant_schemes.c, the modal damping matrix is built in plant_damping.c.
 */
#ifndef FLEXARM_PLANT_MODEL_H
#define FLEXARM_PLANT_MODEL_H

#include "flexarm_physics.h"
#include "plant_constants.h"

#define N PLANT_N_ELEMENTS
#define NZ (2 * N)
#define NA (NZ + 1) /* the exponential scheme's augmented matrix */

/* The model at one state (θ, θ̇), torque excluded: what every use of that state shares. */
typedef struct {
    double c[N], s[N];                     /* cos θ, sin θ */
    double mass_packed[PLANT_N_MASS_PACKED]; /* M(θ), lower triangle column by column */
    double unit_lower[PLANT_N_UNIT_LOWER];   /* M = L D Lᵀ: L below the diagonal, column by column */
    double inverse_pivots[N], pivots[N];   /* 1/d_j, d_j */
    double force[N];                       /* S(θ, θ̇) − C_d θ̇ */
} Eval;

typedef struct {
    double mass0[N * N], mass1[N * N]; /* M_jk(payload) = mass0 + payload * mass1, row-major */
    double springs_brackets[PLANT_N_SPRING_VALUES], springs_links[PLANT_N_SPRING_VALUES]; /* stiffness non-zeros */
    double length[N];
    /* the model at (model_payload, model_ratio, model_scale) */
    double coeff[N * N + PLANT_N_SPRING_VALUES]; /* (M_jk row-major, stiffness non-zeros) */
    double damping[N * N];                        /* C_d, symmetric */
    int damped, model_ready;
    double model_payload, model_ratio, model_scale;
    /* the evaluation at the last state whose outputs were computed: the next step starts there */
    Eval cache;
    double cache_z[NZ];
    int cache_valid;
    double w[PLANT_WORK_DOUBLES];
    long long iw[PLANT_WORK_INTS];
} PlantData;

/* -- the model at a state (plant.c) -- */
int evaluate(PlantData *d, const double *z, Eval *ev);
/* x = M⁻¹ b at the state of `ev` (x and b distinct) */
void mass_solve(PlantData *d, const Eval *ev, const double *b, double *x);
void mass_full(const Eval *ev, double *mass);
/* θ̈ = M⁻¹ (S − C_d θ̇ + B̄τ), `forces` = B̄τ */
void acceleration(PlantData *d, const Eval *ev, const double *forces, double *acc);
/* Q and V − C_d (column-major) at the state of `ev` with rates omega and accelerations acc. */
void tangents(PlantData *d, const Eval *ev, const double *omega, const double *acc, double *q, double *v);

/* -- one substep of each scheme (plant_schemes.c): z_new from z, whose evaluation is ev0; ev is workspace;
      0, or -1 when a matrix is singular or the stage equations do not converge -- */
int rodas4_step(PlantData *d, const double *z, const Eval *ev0, Eval *ev, const double *forces, double h,
                double *z_new, double *err, double *err_angle);
int exponential_step(PlantData *d, const double *z, const Eval *ev0, const double *forces, double h,
                     double *z_new);
int gauss_step(PlantData *d, const double *z, const Eval *ev0, Eval *ev, const double *forces, double h,
               double *z_new, int *iterations);
/* `steps` RK4 steps of size h (the reference scheme; no evaluation carried in) */
int rk4_steps(PlantData *d, const double *z, Eval *ev, const double *forces, double h, int steps, double *z_new);

/* -- modal damping (plant_damping.c) -- */
int build_damping(PlantData *d, double ratio);

#endif
