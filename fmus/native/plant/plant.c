/*
 * Native plant FMU: the Sandia two-link flexible arm, 11-element model.
 *
 * The physics is not written here: flexarm_physics.c is generated at build time
 * by CasADi from flexarm._kernels itself (its NumPy path evaluated on symbols,
 * fmus/native/physics_codegen.py): the mass matrix M(θ), the right-hand side
 * S(θ, θ̇) + B̄τ and the tangent matrices ∂(S − Mθ̈)/∂θ, ∂S/∂θ̇. This file holds the numerical
 * method of flexarm._kernels (RODAS4 with the reduced stage system, the same
 * coefficients and substeps), the sensor-point kinematics and the FMI mapping.
 * Arm constants come from resources/arm_parameters.txt (SHA-256 checked).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_glue.h"
#include "flexarm_physics.h"
#include "model_vars.h"
#include "portable_math.h"
#include "plant_constants.h"

#define N PLANT_N_ELEMENTS
#define NZ (2 * N)

typedef struct {
    double mass0[N * N], mass1[N * N]; /* M_jk(payload) = mass0 + payload * mass1, row-major */
    double springs[PLANT_N_SPRING_VALUES];
    double length[N];
    double coeff[N * N + PLANT_N_SPRING_VALUES]; /* (M_jk row-major, stiffness non-zeros) at the current payload */
    double w[PLANT_WORK_DOUBLES];
    long long iw[PLANT_WORK_INTS];
} PlantData;

typedef struct {
    double z[NZ];
    double tau_held[2];
    double last_error;
    double payload; /* payload of coeff[] */
} PlantState;

/* -- generated physics, wrapped ---------------------------------------------------------------- */
static void mass_rhs(PlantData *d, const double *z, const double *tau, double *mass, double *rhs)
{
    const double *arg[4] = {z, z + N, tau, d->coeff};
    double *res[2] = {mass, rhs};
    flexarm_mass_rhs(arg, res, d->iw, d->w, 0);
}

static void tangents(PlantData *d, const double *z, const double *acc, double *q, double *v)
{
    const double *arg[4] = {z, z + N, acc, d->coeff};
    double *res[2] = {q, v};
    flexarm_tangents(arg, res, d->iw, d->w, 0);
}

/* -- small dense linear algebra (n = 11), as flexarm._kernels ------------------------------------ */
static int cholesky(double *a) /* lower factor in place (column-major = row-major: a is symmetric) */
{
    for (int j = 0; j < N; j++) {
        double dd = a[j * N + j];
        for (int k = 0; k < j; k++) dd -= a[j * N + k] * a[j * N + k];
        if (!(dd > 0.0)) return -1;
        a[j * N + j] = sqrt(dd);
        for (int i = j + 1; i < N; i++) {
            double s = a[i * N + j];
            for (int k = 0; k < j; k++) s -= a[i * N + k] * a[j * N + k];
            a[i * N + j] = s / a[j * N + j];
        }
    }
    return 0;
}

static void cholesky_solve(const double *low, double *x)
{
    for (int i = 0; i < N; i++) {
        for (int k = 0; k < i; k++) x[i] -= low[i * N + k] * x[k];
        x[i] /= low[i * N + i];
    }
    for (int i = N - 1; i >= 0; i--) {
        for (int k = i + 1; k < N; k++) x[i] -= low[k * N + i] * x[k];
        x[i] /= low[i * N + i];
    }
}

static int lu_factor(double *lu, int *piv)
{
    for (int i = 0; i < N; i++) piv[i] = i;
    for (int k = 0; k < N; k++) {
        int p = k;
        double big = fabs(lu[k * N + k]);
        for (int i = k + 1; i < N; i++)
            if (fabs(lu[i * N + k]) > big) big = fabs(lu[i * N + k]), p = i;
        if (big == 0.0) return -1;
        if (p != k) {
            for (int j = 0; j < N; j++) {
                double t = lu[k * N + j];
                lu[k * N + j] = lu[p * N + j];
                lu[p * N + j] = t;
            }
            int t = piv[k];
            piv[k] = piv[p];
            piv[p] = t;
        }
        for (int i = k + 1; i < N; i++) {
            lu[i * N + k] /= lu[k * N + k];
            double f = lu[i * N + k];
            for (int j = k + 1; j < N; j++) lu[i * N + j] -= f * lu[k * N + j];
        }
    }
    return 0;
}

static void lu_solve(const double *lu, const int *piv, const double *b, double *x)
{
    for (int i = 0; i < N; i++) x[i] = b[piv[i]];
    for (int i = 0; i < N; i++)
        for (int k = 0; k < i; k++) x[i] -= lu[i * N + k] * x[k];
    for (int i = N - 1; i >= 0; i--) {
        for (int k = i + 1; k < N; k++) x[i] -= lu[i * N + k] * x[k];
        x[i] /= lu[i * N + i];
    }
}

/* θ̈ at (z, τ) into acc; the mass matrix into mass (overwritten by its factor). */
static int acceleration(PlantData *d, const double *z, const double *tau, double *mass, double *acc)
{
    mass_rhs(d, z, tau, mass, acc);
    if (cholesky(mass) != 0) return -1;
    cholesky_solve(mass, acc);
    return 0;
}

/* One RODAS4 step of size h (flexarm._kernels._rodas4_step_vectorised); -1 if a matrix is singular. */
static int rodas4_step(PlantData *d, const double *z, const double *tau, double h, double *z_new, double *err)
{
    double mass[N * N], chol[N * N], q[N * N], v[N * N], w[N * N], f[NZ], ks[6][NZ], u[NZ], b[N], k_th[N];
    int piv[N];
    mass_rhs(d, z, tau, mass, f + N);
    memcpy(chol, mass, sizeof mass);
    if (cholesky(chol) != 0) return -1;
    cholesky_solve(chol, f + N);
    tangents(d, z, f + N, q, v); /* column-major: q[i + j N] = Q_ij */
    const double g = 1.0 / (RODAS4_GAMMA * h);
    for (int i = 0; i < N; i++)
        for (int j = 0; j < N; j++) w[i * N + j] = g * g * mass[i * N + j] - g * v[i + j * N] - q[i + j * N];
    if (lu_factor(w, piv) != 0) return -1;
    memcpy(f, z + N, N * sizeof *f);
    memcpy(u, z, sizeof u);
    for (int stage = 0; stage < 6; stage++) {
        if (stage > 0) {
            if (stage < 5) {
                memcpy(u, z, sizeof u);
                for (int j = 0; j < stage; j++)
                    for (int i = 0; i < NZ; i++) u[i] += RODAS4_A[stage][j] * ks[j][i];
            } else {
                for (int i = 0; i < NZ; i++) u[i] += ks[4][i];
            }
            memcpy(f, u + N, N * sizeof *f);
            if (acceleration(d, u, tau, chol, f + N) != 0) return -1;
            for (int j = 0; j < stage; j++) {
                double cj = RODAS4_C[stage][j] / h;
                for (int i = 0; i < NZ; i++) f[i] += cj * ks[j][i];
            }
        }
        for (int i = 0; i < N; i++) { /* M (r_ω + g r_θ) − V r_θ */
            double t = 0.0;
            for (int j = 0; j < N; j++) t += mass[i * N + j] * (f[N + j] + g * f[j]);
            double s = 0.0;
            for (int j = 0; j < N; j++) s += v[i + j * N] * f[j];
            b[i] = t - s;
        }
        lu_solve(w, piv, b, k_th);
        for (int i = 0; i < N; i++) {
            ks[stage][i] = k_th[i];
            ks[stage][N + i] = g * k_th[i] - f[i];
        }
    }
    double e = 0.0;
    for (int i = 0; i < NZ; i++) {
        z_new[i] = u[i] + ks[5][i];
        e = fmax(e, fabs(ks[5][i]));
    }
    *err = e;
    return 0;
}

/* -- outputs -------------------------------------------------------------------------------- */
static int outputs(Instance *inst, const double *z, const double *tau)
{
    PlantData *d = inst->data;
    double mass[N * N], alpha[N];
    if (acceleration(d, z, tau, mass, alpha) != 0) return -1;
    double *y = inst->values;
    for (int i = 0; i < N; i++) {
        y[IDX_THETA[i]] = z[i];
        y[IDX_OMEGA[i]] = z[N + i];
    }
    y[IDX_q1] = z[0];
    y[IDX_q2] = z[PLANT_JOINT2_DISTAL] - z[PLANT_JOINT2_PROXIMAL];
    y[IDX_qd1] = z[N];
    y[IDX_qd2] = z[N + PLANT_JOINT2_DISTAL] - z[N + PLANT_JOINT2_PROXIMAL];
    static const int gauge[6] = PLANT_STRAIN_GAUGE_ELEMENTS;
    for (int k = 0; k < 6; k++) y[IDX_EPS[k]] = z[gauge[k]] - z[gauge[k] - 1];
    /* flexarm._kernels.chain_kinematics for the link tips */
    double x = 0.0, yy = 0.0, ax = 0.0, ay = 0.0;
    for (int i = 0; i < N; i++) {
        double c = flexarm_cos(z[i]), s = flexarm_sin(z[i]), om2 = z[N + i] * z[N + i], l = d->length[i];
        x += l * c;
        yy += l * s;
        ax += l * (-s * alpha[i] - c * om2);
        ay += l * (c * alpha[i] - s * om2);
        if (i == PLANT_LINK1_TIP) {
            y[IDX_link1_tip_ax] = ax;
            y[IDX_link1_tip_ay] = ay;
            y[IDX_acc1_n] = -s * ax + c * ay;
        }
        if (i == PLANT_LINK2_TIP) {
            y[IDX_tip_x] = x;
            y[IDX_tip_y] = yy;
            y[IDX_link2_tip_ax] = ax;
            y[IDX_link2_tip_ay] = ay;
            y[IDX_acc2_n] = -s * ax + c * ay;
        }
    }
    return 0;
}

/* -- model callbacks ----------------------------------------------------------------------------- */
static int plant_load(Instance *inst, char *const *contents, const size_t *sizes)
{
    (void)sizes;
    PlantData *d = calloc(1, sizeof *d);
    if (d == NULL) return -1;
    const char *file = MODEL_INFO.resources[0].file, *text = contents[0];
    if (glue_read_doubles(inst, file, text, "mass_coefficients_no_payload", d->mass0, N * N) ||
        glue_read_doubles(inst, file, text, "mass_coefficients_per_kg_payload", d->mass1, N * N) ||
        glue_read_doubles(inst, file, text, "spring_stiffness", d->springs, PLANT_N_SPRING_VALUES) ||
        glue_read_doubles(inst, file, text, "length", d->length, N)) {
        free(d);
        return -1;
    }
    inst->data = d;
    return 0;
}

static void plant_unload(Instance *inst)
{
    free(inst->data);
    inst->data = NULL;
}

static void set_payload(PlantData *d, PlantState *st, double payload)
{
    for (int k = 0; k < N * N; k++) d->coeff[k] = d->mass0[k] + payload * d->mass1[k];
    memcpy(d->coeff + N * N, d->springs, sizeof d->springs);
    st->payload = payload;
}

static fmi2Status plant_initialize(Instance *inst)
{
    PlantState *st = inst->state;
    PlantData *d = inst->data;
#ifdef HAS_VAR_integrator /* the Python plant's choice of scheme: the native plant has RODAS4 (1) only */
    if (VALUE(inst, IDX_integrator) != 1) {
        glue_log(inst, fmi2Error, "fmi2ExitInitializationMode: integrator = %g: the native plant implements 1 "
                 "(rodas4) only; use the Python plant for the others", VALUE(inst, IDX_integrator));
        return fmi2Error;
    }
#endif
#ifdef HAS_VAR_damping_ratio
    if (VALUE(inst, IDX_damping_ratio) != 0) {
        glue_log(inst, fmi2Error, "fmi2ExitInitializationMode: damping_ratio = %g: the native plant implements 0 "
                 "(no structural damping) only; use the Python plant for damping", VALUE(inst, IDX_damping_ratio));
        return fmi2Error;
    }
#endif
    set_payload(d, st, VALUE(inst, IDX_payload_mass));
    double z[NZ] = {0}, tau[2] = {VALUE(inst, IDX_tau1), VALUE(inst, IDX_tau2)};
    for (int i = 0; i < N; i++) /* flexarm.model.rigid_configuration(q1_0, q2_0), at rest */
        z[i] = VALUE(inst, IDX_q1_0) + (i >= PLANT_JOINT2_DISTAL ? VALUE(inst, IDX_q2_0) : 0.0);
    if (outputs(inst, z, tau) != 0) {
        glue_log(inst, fmi2Error, "fmi2ExitInitializationMode: the mass matrix is not positive definite at "
                 "q1_0 = %g rad, q2_0 = %g rad", VALUE(inst, IDX_q1_0), VALUE(inst, IDX_q2_0));
        return fmi2Error;
    }
    memcpy(st->z, z, sizeof z);
    memcpy(st->tau_held, tau, sizeof tau);
    st->last_error = 0.0;
    return fmi2OK;
}

static fmi2Status plant_do_step(Instance *inst, double t, double h)
{
    PlantState *st = inst->state;
    PlantData *d = inst->data;
    if (st->payload != VALUE(inst, IDX_payload_mass)) set_payload(d, st, VALUE(inst, IDX_payload_mass));
    const double tau[2] = {VALUE(inst, IDX_tau1), VALUE(inst, IDX_tau2)};
    const int substeps = (int)VALUE(inst, IDX_substeps);
    double z[NZ], z_new[NZ], err = 0.0;
    memcpy(z, st->z, sizeof z);
    const double hs = h / substeps;
    int ok = 1;
    for (int k = 0; k < substeps && ok; k++) {
        double e;
        ok = rodas4_step(d, z, tau, hs, z_new, &e) == 0;
        for (int i = 0; i < NZ && ok; i++) ok = isfinite(z_new[i]);
        err = fmax(err, e);
        memcpy(z, z_new, sizeof z);
    }
    /* Outputs are written into the values only after the step succeeded (a failed one changes nothing). */
    double saved[MODEL_N_VARS];
    memcpy(saved, inst->values, sizeof saved);
    if (!ok || outputs(inst, z, tau) != 0) {
        memcpy(inst->values, saved, sizeof saved);
        glue_log(inst, fmi2Discard, "fmi2DoStep: state became non-finite (tau1 = %.17g N.m, tau2 = %.17g N.m, "
                 "h = %.17g s, t = %.17g s, substeps = %d); the state stays at t", tau[0], tau[1], h, t, substeps);
        return fmi2Discard;
    }
    memcpy(st->z, z, sizeof z);
    memcpy(st->tau_held, tau, sizeof tau);
    st->last_error = err;
    return fmi2OK;
}

const ModelInfo MODEL_INFO = {
    MODEL_IDENTIFIER_STRING, MODEL_GUID_STRING, MODEL_VARS, MODEL_N_VARS, MODEL_RESOURCES, MODEL_N_RESOURCES,
    sizeof(PlantState), plant_load, plant_unload, plant_initialize, NULL, plant_do_step,
};
