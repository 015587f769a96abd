/*
 * Native plant FMU: the Sandia two-link flexible arm, 11-element model.
 *
 * The physics is not written here: flexarm_physics.c is generated at build time
 * by CasADi from flexarm._kernels itself (its NumPy path evaluated on symbols,
 * fmu_build/native_codegen.py): the mass matrix M(θ), the right-hand side
 * S(θ, θ̇), the input forces B̄τ and the tangent matrices ∂(S − Mθ̈)/∂θ, ∂S/∂θ̇, all
 * from cos θ and sin θ (computed once per state here, shared by every use). This file
 * holds the model at a state, the communication step (scheme, substeps per millisecond and RODAS4's error
 * control, as flexarm.integrator), the sensor-point kinematics and the FMI mapping. The schemes of one substep
 * (flexarm._integrator_kernels) are in plant_schemes.c, the modal damping matrix in plant_damping.c; the types
 * they share are in plant_model.h.
 * Arm constants come from resources/arm_parameters.txt (SHA-256 checked).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_glue.h"
#include "flexarm_physics.h"
#include "loop_index.h"
#include "model_vars.h"
#include "plant_constants.h"
#include "plant_linalg.h"
#include "plant_model.h"
#include "portable_math.h"

typedef struct {
    double z[NZ];
    double tau_held[2];
    double last_error;
    double start_time; /* the run's start (s): the exponential scheme's horizon counts from it */
} PlantState;

/* flexarm.integrator.INTEGRATORS, the FMU's `integrator` values */
enum { SCHEME_RODAS4 = 1, SCHEME_EXPONENTIAL = 2, SCHEME_GAUSS = 3, SCHEME_REFERENCE = 4 };

/* -- the model at a state ------------------------------------------------------------------------ */
int evaluate(PlantData *d, const double *z, Eval *ev)
{
    for (int i = 0; i < N; i++) flexarm_sincos(z[i], &ev->s[i], &ev->c[i]);
    const double *arg[4] = {ev->c, ev->s, z + N, d->coeff};
    double *res[5] = {ev->mass_packed, ev->force, ev->unit_lower, ev->inverse_pivots, ev->pivots};
    flexarm_mass_rhs(arg, res, d->iw, d->w, 0);
    if (d->damped)
        for (int i = 0; i < N; i++) {
            double t = 0.0;
            for (int j = 0; j < N; j++) t += d->damping[i * N + j] * z[N + j];
            ev->force[i] -= t;
        }
    for (int j = 0; j < N; j++)
        if (!(ev->pivots[j] > 0.0)) return -1; /* M not positive definite (or not finite) */
    return 0;
}

/* x = M⁻¹ b at the state of `ev` (x and b distinct) */
void mass_solve(PlantData *d, const Eval *ev, const double *b, double *x)
{
    const double *arg[3] = {ev->unit_lower, ev->inverse_pivots, b};
    double *res[1] = {x};
    flexarm_ldl_solve(arg, res, d->iw, d->w, 0);
}

void mass_full(const Eval *ev, double *mass)
{
    for (int j = 0, k = 0; j < N; j++)
        for (int i = j; i < N; i++, k++) mass[j * N + i] = mass[i * N + j] = ev->mass_packed[k];
}

/* θ̈ = M⁻¹ (S − C_d θ̇ + B̄τ), `forces` = B̄τ */
void acceleration(PlantData *d, const Eval *ev, const double *forces, double *acc)
{
    double b[N];
    for (int i = 0; i < N; i++) b[i] = ev->force[i] + forces[i];
    mass_solve(d, ev, b, acc);
}

/* x = W⁻¹ b with W's factors from lu_factor */
void tangents(PlantData *d, const Eval *ev, const double *omega, const double *acc, double *q, double *v)
{
    const double *arg[5] = {ev->c, ev->s, omega, acc, d->coeff};
    double *res[2] = {q, v};
    flexarm_tangents(arg, res, d->iw, d->w, 0);
    if (d->damped)
        for (int k = 0; k < N * N; k++) v[k] -= d->damping[k]; /* symmetric: either layout */
}

static void input_forces(PlantData *d, const double *tau, double *forces)
{
    const double *arg[1] = {tau};
    double *res[1] = {forces};
    flexarm_input_forces(arg, res, d->iw, d->w, 0);
}

/* The model at (payload, ratio, scale): mass and stiffness coefficients, damping matrix. The stiffness is the
   brackets' springs plus `scale` times the links' (flexarm.parameters.ArmParameters.stiffness_matrix). */
static int set_model(PlantData *d, double payload, double ratio, double scale)
{
    if (d->model_ready && d->model_payload == payload && d->model_ratio == ratio && d->model_scale == scale)
        return 0;
    for (int k = 0; k < N * N; k++) d->coeff[k] = d->mass0[k] + payload * d->mass1[k];
    for (int k = 0; k < PLANT_N_SPRING_VALUES; k++)
        d->coeff[N * N + k] = d->springs_brackets[k] + scale * d->springs_links[k];
    d->cache_valid = 0;
    d->model_ready = 0;
    if (build_damping(d, ratio) != 0) return -1;
    d->model_payload = payload;
    d->model_ratio = ratio;
    d->model_scale = scale;
    d->model_ready = 1;
    return 0;
}

/* -- outputs -------------------------------------------------------------------------------------- */
/* The sample indices (flexarm/loop_index.py): the outputs' sample at t, the lag of the torque held since held_from
   (the tau_index present came with it). */
static void index_outputs(Instance *inst, double t, double held_from, const double tau[2])
{
    VALUE(inst, IDX_sample_index) = loop_index_of_time(t);
    VALUE(inst, IDX_tau_lag) = loop_torque_lag(held_from, VALUE(inst, IDX_tau_index));
    VALUE(inst, IDX_tau1_applied) = tau[0]; /* the torque held, as received */
    VALUE(inst, IDX_tau2_applied) = tau[1];
}

static void outputs(PlantData *d, Instance *inst, const double *z, const Eval *ev, const double *tau)
{
    double alpha[N], forces[N];
    input_forces(d, tau, forces);
    acceleration(d, ev, forces, alpha);
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
        const double c = ev->c[i], s = ev->s[i], om2 = z[N + i] * z[N + i], l = d->length[i];
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
    memcpy(&d->cache, ev, sizeof *ev);
    memcpy(d->cache_z, z, sizeof d->cache_z);
    d->cache_valid = 1;
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
        glue_read_doubles(inst, file, text, "spring_stiffness_brackets", d->springs_brackets,
                          PLANT_N_SPRING_VALUES) ||
        glue_read_doubles(inst, file, text, "spring_stiffness_links", d->springs_links, PLANT_N_SPRING_VALUES) ||
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

static double damping_ratio(const Instance *inst)
{
#ifdef HAS_VAR_damping_ratio
    return VALUE(inst, IDX_damping_ratio);
#else
    (void)inst;
    return 0.0;
#endif
}

static double link_stiffness_scale(const Instance *inst)
{
#ifdef HAS_VAR_link_stiffness_scale
    return VALUE(inst, IDX_link_stiffness_scale);
#else
    (void)inst;
    return 1.0;
#endif
}

static int scheme(const Instance *inst)
{
#ifdef HAS_VAR_integrator /* the Python plant's choice: 1 rodas4, 2 exponential, 3 gauss, 4 reference */
    return (int)VALUE(inst, IDX_integrator);
#else
    (void)inst;
    return SCHEME_RODAS4;
#endif
}

/* flexarm.integrator.substep_count: ceil(h [ms] * substeps per ms), at least 1 (RK4 steps for the reference) */
static long substep_count(double h, int substeps, int which)
{
    const double per_ms = (double)substeps * (which == SCHEME_REFERENCE ? PLANT_REFERENCE_STEPS_PER_SUBSTEP : 1);
    const double n = ceil(h / 1e-3 * per_ms - 1e-6);
    return n < 1.0 ? 1 : (n > 1e9 ? 1000000000L : (long)n);
}

static fmi2Status plant_initialize(Instance *inst)
{
    PlantState *st = inst->state;
    PlantData *d = inst->data;
    if (set_model(d, VALUE(inst, IDX_payload_mass), damping_ratio(inst), link_stiffness_scale(inst)) != 0) {
        glue_log(inst, fmi2Error, "fmi2ExitInitializationMode: the modal damping matrix could not be built "
                 "(payload_mass = %g kg, damping_ratio = %g, link_stiffness_scale = %g)", VALUE(inst, IDX_payload_mass),
                 damping_ratio(inst), link_stiffness_scale(inst));
        return fmi2Error;
    }
    double z[NZ] = {0}, tau[2] = {VALUE(inst, IDX_tau1), VALUE(inst, IDX_tau2)};
    for (int i = 0; i < N; i++) /* flexarm.model.rigid_configuration(q1_0, q2_0), at rest */
        z[i] = VALUE(inst, IDX_q1_0) + (i >= PLANT_JOINT2_DISTAL ? VALUE(inst, IDX_q2_0) : 0.0);
    Eval ev;
    if (evaluate(d, z, &ev) != 0) {
        glue_log(inst, fmi2Error, "fmi2ExitInitializationMode: the mass matrix is not positive definite at "
                 "q1_0 = %g rad, q2_0 = %g rad", VALUE(inst, IDX_q1_0), VALUE(inst, IDX_q2_0));
        return fmi2Error;
    }
    outputs(d, inst, z, &ev, tau);
    index_outputs(inst, inst->time, inst->time, tau);
    memcpy(st->z, z, sizeof z);
    memcpy(st->tau_held, tau, sizeof tau);
    st->last_error = 0.0;
    st->start_time = inst->time;
    return fmi2OK;
}

static fmi2Status plant_do_step(Instance *inst, double t, double h)
{
    PlantState *st = inst->state;
    PlantData *d = inst->data;
    const double tau[2] = {VALUE(inst, IDX_tau1), VALUE(inst, IDX_tau2)};
    const int substeps = (int)VALUE(inst, IDX_substeps), which = scheme(inst);
    if (which == SCHEME_EXPONENTIAL && t + h - st->start_time > PLANT_EXPONENTIAL_HORIZON_S + 1e-9) {
        /* flexarm.integrator.check_horizon */
        glue_log(inst, fmi2Error, "fmi2DoStep: integrator: exponential is only correct up to t = %g s (its energy "
                 "error grows without bound: +56 %% on the gamma = 1 loop at 5 s), asked for t = %.6g s; use gauss "
                 "(no numerical damping, bounded energy error) or reference (RK4 at 2.5 us) for longer runs",
                 PLANT_EXPONENTIAL_HORIZON_S, t + h - st->start_time);
        return fmi2Error;
    }
    const long count = substep_count(h, substeps, which);
    double z[NZ], z_new[NZ], forces[N], err = 0.0;
    Eval ev_a, ev_b, *at_z = &ev_a, *work = &ev_b;
    /* a restored FMU state of another instance may carry another payload, damping or stiffness */
    int ok = set_model(d, VALUE(inst, IDX_payload_mass), damping_ratio(inst), link_stiffness_scale(inst)) == 0;
    memcpy(z, st->z, sizeof z);
    if (ok && d->cache_valid && memcmp(d->cache_z, z, sizeof z) == 0) at_z = &d->cache;
    else ok = ok && evaluate(d, z, at_z) == 0;
    input_forces(d, tau, forces);
    const double hs = h / (double)count;
    if (ok && which == SCHEME_REFERENCE) { /* RK4 needs no evaluation carried between steps */
        ok = rk4_steps(d, z, work, forces, hs, (int)count, z_new) == 0;
        for (int i = 0; i < NZ && ok; i++) ok = isfinite(z_new[i]);
        memcpy(z, z_new, sizeof z);
        at_z = &ev_a;
        ok = ok && evaluate(d, z, at_z) == 0;
    } else {
        /* RODAS4 is error-controlled (flexarm._kernels.advance): a substep whose embedded estimate exceeds
           RODAS4_ANGLE_TOL on an angle is redone at half the length, at most RODAS4_MAX_HALVINGS times, and the
           rest of the step keeps the shorter length; positions count in units of the shortest allowed substep. */
        const long total = count << RODAS4_MAX_HALVINGS;
        long pos = 0;
        int level = 0;
        while (pos < total && ok) {
            double e = 0.0, e_angle = 0.0;
            int iterations = 0;
            if (which == SCHEME_EXPONENTIAL) ok = exponential_step(d, z, at_z, forces, hs, z_new) == 0;
            else if (which == SCHEME_GAUSS) ok = gauss_step(d, z, at_z, work, forces, hs, z_new, &iterations) == 0;
            else ok = rodas4_step(d, z, at_z, work, forces, h / (double)(count << level), z_new, &e, &e_angle) == 0;
            for (int i = 0; i < NZ && ok; i++) ok = isfinite(z_new[i]);
            if (ok && which == SCHEME_RODAS4 && level < RODAS4_MAX_HALVINGS && e_angle > RODAS4_ANGLE_TOL) {
                level++; /* rejected: z and its evaluation are unchanged */
                continue;
            }
            err = fmax(err, e);
            memcpy(z, z_new, sizeof z);
            if (at_z == &d->cache) at_z = &ev_a;
            ok = ok && evaluate(d, z, at_z) == 0; /* the next substep's start, or the outputs' state */
            pos += 1L << (RODAS4_MAX_HALVINGS - level);
        }
    }
    if (!ok) { /* a failed step changes nothing */
        glue_log(inst, fmi2Discard, "fmi2DoStep: state became non-finite or the stage equations did not converge "
                 "(tau1 = %.17g N.m, tau2 = %.17g N.m, h = %.17g s, t = %.17g s, substeps = %d per ms); the state "
                 "stays at t", tau[0], tau[1], h, t, substeps);
        return fmi2Discard;
    }
    outputs(d, inst, z, at_z, tau);
    index_outputs(inst, t + h, t, tau);
    memcpy(st->z, z, sizeof z);
    memcpy(st->tau_held, tau, sizeof tau);
    st->last_error = err;
    return fmi2OK;
}

const ModelInfo MODEL_INFO = {
    MODEL_IDENTIFIER_STRING, MODEL_GUID_STRING, MODEL_VARS, MODEL_N_VARS, MODEL_RESOURCES, MODEL_N_RESOURCES,
    sizeof(PlantState), plant_load, plant_unload, plant_initialize, NULL, plant_do_step,
};
