/*
 * Native plant FMU: the Sandia two-link flexible arm, 11-element model.
 *
 * The physics is not written here: flexarm_physics.c is generated at build time
 * by CasADi from flexarm._kernels itself (its NumPy path evaluated on symbols,
 * fmu_build/native_codegen.py): the mass matrix M(θ), the right-hand side
 * S(θ, θ̇), the input forces B̄τ and the tangent matrices ∂(S − Mθ̈)/∂θ, ∂S/∂θ̇, all
 * from cos θ and sin θ (computed once per state here, shared by every use). This file
 * holds the numerical methods of flexarm._integrator_kernels (RODAS4 with the reduced stage system,
 * the exponential Rosenbrock-Euler step, 2-stage Gauss-Legendre collocation with simplified
 * Newton, the RK4 reference; the same coefficients, tolerances and substeps per millisecond as
 * flexarm.integrator), the sensor-point kinematics and the FMI mapping. The modal damping matrix is
 * built in plant_damping.c; the types both share are in plant_model.h.
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
static void stage_solve(PlantData *d, const double *lu, const int *piv, const double *b, double *x)
{
    double bp[N];
    for (int i = 0; i < N; i++) bp[i] = b[piv[i]];
    const double *arg[2] = {lu, bp};
    double *res[1] = {x};
    flexarm_lu_solve(arg, res, d->iw, d->w, 0);
}

/* Q and V − C_d (column-major) at the state of `ev` with rates omega and accelerations acc. */
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

/* -- RODAS4 (flexarm._integrator_kernels._rodas4_step_loops) -------------------------------------- */
/* One step of size h from z, whose evaluation is `ev0`; `ev` is workspace. -1 if a matrix is singular. */
static int rodas4_step(PlantData *d, const double *z, const Eval *ev0, Eval *ev, const double *forces, double h,
                       double *z_new, double *err, double *err_angle)
{
    double mass[N * N], q[N * N], v[N * N], w[N * N], f[NZ], ks[6][NZ], u[NZ], r[N], tm[N], tv[N], k_th[N];
    int piv[N];
    mass_full(ev0, mass);
    memcpy(f, z + N, N * sizeof *f);
    acceleration(d, ev0, forces, f + N);
    tangents(d, ev0, z + N, f + N, q, v);
    const double g = 1.0 / (RODAS4_GAMMA * h);
    for (int i = 0; i < N; i++)
        for (int j = 0; j < N; j++) w[i * N + j] = g * g * mass[i * N + j] - g * v[i + j * N] - q[i + j * N];
    if (lu_factor(w, piv, N) != 0) return -1;
    memcpy(u, z, sizeof u);
    for (int stage = 0; stage < 6; stage++) {
        if (stage > 0) {
            if (stage < 5) {
                for (int i = 0; i < NZ; i++) {
                    double t = z[i];
                    for (int j = 0; j < stage; j++) t += RODAS4_A[stage][j] * ks[j][i];
                    u[i] = t;
                }
            } else {
                for (int i = 0; i < NZ; i++) u[i] += ks[4][i];
            }
            memcpy(f, u + N, N * sizeof *f);
            if (evaluate(d, u, ev) != 0) return -1;
            acceleration(d, ev, forces, f + N);
            for (int j = 0; j < stage; j++) {
                const double cj = RODAS4_C[stage][j] / h;
                for (int i = 0; i < NZ; i++) f[i] += cj * ks[j][i];
            }
        }
        /* M (r_ω + g r_θ) − V r_θ, row by row in j order; M symmetric and V column-major give columns */
        for (int j = 0; j < N; j++) r[j] = f[N + j] + g * f[j];
        for (int i = 0; i < N; i++) tm[i] = tv[i] = 0.0;
        for (int j = 0; j < N; j++) {
            const double *mj = mass + j * N, *vj = v + j * N;
            for (int i = 0; i < N; i++) {
                tm[i] += mj[i] * r[j];
                tv[i] += vj[i] * f[j];
            }
        }
        for (int i = 0; i < N; i++) tm[i] -= tv[i];
        stage_solve(d, w, piv, tm, k_th);
        for (int i = 0; i < N; i++) {
            ks[stage][i] = k_th[i];
            ks[stage][N + i] = g * k_th[i] - f[i];
        }
    }
    double e = 0.0;
    for (int i = 0; i < NZ; i++) {
        z_new[i] = u[i] + ks[5][i];
        e = fmax(e, fabs(ks[5][i]));
        if (i == N - 1) *err_angle = e; /* the embedded estimate's largest angle component */
    }
    *err = e;
    return 0;
}

/* -- exponential Rosenbrock-Euler (flexarm._integrator_kernels.exponential_euler_step) ------------ */
static int exponential_step(PlantData *d, const double *z, const Eval *ev0, const double *forces, double h,
                            double *z_new)
{
    double acc[N], q[N * N], v[N * N], aug[NA * NA], e[NA * NA];
    acceleration(d, ev0, forces, acc);
    tangents(d, ev0, z + N, acc, q, v);
    double qv[N * N], vv[N * N];
    memcpy(qv, q, sizeof qv);
    memcpy(vv, v, sizeof vv);
    for (int j = 0; j < N; j++) { /* [∂θ̈/∂θ, ∂θ̈/∂θ̇] = M⁻¹ [Q, V − C_d], column by column */
        mass_solve(d, ev0, qv + j * N, q + j * N);
        mass_solve(d, ev0, vv + j * N, v + j * N);
    }
    double c = 1.0; /* sqrt(max |∂θ̈_i/∂θ_i|): balances the blocks of hJ */
    for (int i = 0; i < N; i++) c = fmax(c, sqrt(fabs(q[i * N + i])));
    memset(aug, 0, sizeof aug);
    for (int i = 0; i < N; i++) {
        aug[i * NA + N + i] = h * c;
        aug[i * NA + NZ] = h * z[N + i];
        aug[(N + i) * NA + NZ] = h * acc[i] / c;
        for (int j = 0; j < N; j++) {
            aug[(N + i) * NA + j] = h * q[j * N + i] / c;
            aug[(N + i) * NA + N + j] = h * v[j * N + i];
        }
    }
    if (expm(aug, e, NA) != 0) return -1;
    for (int i = 0; i < N; i++) {
        z_new[i] = z[i] + e[i * NA + NZ];
        z_new[N + i] = z[N + i] + c * e[(N + i) * NA + NZ];
    }
    return 0;
}

/* -- 2-stage Gauss-Legendre (flexarm._integrator_kernels.gauss_step) ------------------------------ */
/* M K at the state of `ev` (packed lower triangle, column by column) */
static void mass_times(const Eval *ev, const double *k, double *out)
{
    for (int i = 0; i < N; i++) out[i] = 0.0;
    for (int j = 0, p = 0; j < N; j++)
        for (int i = j; i < N; i++, p++) {
            out[i] += ev->mass_packed[p] * k[j];
            if (i != j) out[j] += ev->mass_packed[p] * k[i];
        }
}

/* One step of size h from z (evaluation `ev0`); `ev` is workspace. -1 if the stage equations do not converge
   or a matrix is singular. *iterations: the Newton iterations used. */
static int gauss_step(PlantData *d, const double *z, const Eval *ev0, Eval *ev, const double *forces, double h,
                      double *z_new, int *iterations)
{
    enum { M2 = 2 * N };
    double acc[N], q[N * N], v[N * N], mass[N * N], w[M2 * M2], k[M2], g[M2], dk[M2], th[NZ], mk[N];
    int piv[M2];
    mass_full(ev0, mass);
    acceleration(d, ev0, forces, acc);
    tangents(d, ev0, z + N, acc, q, v);
    for (int bi = 0; bi < 2; bi++)
        for (int bj = 0; bj < 2; bj++) {
            const double ca2 = h * h * GAUSS_A2[bi][bj], ca = h * GAUSS_A[bi][bj];
            for (int i = 0; i < N; i++)
                for (int j = 0; j < N; j++)
                    w[(bi * N + i) * M2 + bj * N + j] =
                        (bi == bj ? mass[i * N + j] : 0.0) - ca2 * q[i + j * N] - ca * v[i + j * N];
        }
    if (lu_factor(w, piv, M2) != 0) return -1;
    double scale = 1.0, amax = 0.0, wmax = 0.0;
    for (int i = 0; i < N; i++) {
        amax = fmax(amax, fabs(acc[i]));
        wmax = fmax(wmax, fabs(z[N + i]));
        k[i] = k[N + i] = acc[i];
    }
    scale += amax + wmax / h;
    double last = HUGE_VAL;
    int converged = 0;
    *iterations = 0;
    for (int it = 0; it < GAUSS_MAX_ITER; it++) {
        *iterations = it + 1;
        for (int s = 0; s < 2; s++) {
            for (int i = 0; i < N; i++) {
                th[i] = z[i] + h * GAUSS_C[s] * z[N + i] + h * h * (GAUSS_A2[s][0] * k[i] + GAUSS_A2[s][1] * k[N + i]);
                th[N + i] = z[N + i] + h * (GAUSS_A[s][0] * k[i] + GAUSS_A[s][1] * k[N + i]);
            }
            if (evaluate(d, th, ev) != 0) return -1;
            mass_times(ev, k + s * N, mk);
            for (int i = 0; i < N; i++) g[s * N + i] = mk[i] - (ev->force[i] + forces[i]);
        }
        lu_solve(w, piv, g, dk, M2);
        double step = 0.0;
        for (int i = 0; i < M2; i++) {
            k[i] -= dk[i];
            step = fmax(step, fabs(dk[i]));
        }
        if (!isfinite(step)) break;
        if (step <= GAUSS_TOL * scale) {
            converged = 1;
            break;
        }
        if (it >= 2 && step >= 0.5 * last) { /* no longer contracting: the round-off floor, or too long a step */
            converged = step <= GAUSS_FLOOR * scale;
            break;
        }
        last = step;
    }
    if (!converged) return -1;
    const double b1 = 0.5 * (1.0 - GAUSS_C[0]), b2 = 0.5 * (1.0 - GAUSS_C[1]);
    for (int i = 0; i < N; i++) {
        z_new[i] = z[i] + h * z[N + i] + h * h * (b1 * k[i] + b2 * k[N + i]);
        z_new[N + i] = z[N + i] + 0.5 * h * (k[i] + k[N + i]);
    }
    return 0;
}

/* -- the RK4 reference (flexarm._integrator_kernels.advance_rk4) ---------------------------------- */
static int derivative(PlantData *d, const double *z, Eval *ev, const double *forces, double *out)
{
    if (evaluate(d, z, ev) != 0) return -1;
    memcpy(out, z + N, N * sizeof *out);
    acceleration(d, ev, forces, out + N);
    return 0;
}

/* `steps` RK4 steps of size h from z into z_new (in place allowed). -1 if the mass matrix fails. */
static int rk4_steps(PlantData *d, const double *z, Eval *ev, const double *forces, double h, int steps,
                     double *z_new)
{
    double y[NZ], u[NZ], k1[NZ], k2[NZ], k3[NZ], k4[NZ];
    memcpy(y, z, sizeof y);
    for (int n = 0; n < steps; n++) {
        if (derivative(d, y, ev, forces, k1) != 0) return -1;
        for (int i = 0; i < NZ; i++) u[i] = y[i] + 0.5 * h * k1[i];
        if (derivative(d, u, ev, forces, k2) != 0) return -1;
        for (int i = 0; i < NZ; i++) u[i] = y[i] + 0.5 * h * k2[i];
        if (derivative(d, u, ev, forces, k3) != 0) return -1;
        for (int i = 0; i < NZ; i++) u[i] = y[i] + h * k3[i];
        if (derivative(d, u, ev, forces, k4) != 0) return -1;
        for (int i = 0; i < NZ; i++) y[i] = y[i] + (h / 6.0) * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
    }
    memcpy(z_new, y, sizeof y);
    return 0;
}


/* The model at (payload, ratio): mass and stiffness coefficients, damping matrix. */
static int set_model(PlantData *d, double payload, double ratio)
{
    if (d->model_ready && d->model_payload == payload && d->model_ratio == ratio) return 0;
    for (int k = 0; k < N * N; k++) d->coeff[k] = d->mass0[k] + payload * d->mass1[k];
    memcpy(d->coeff + N * N, d->springs, sizeof d->springs);
    d->cache_valid = 0;
    d->model_ready = 0;
    if (build_damping(d, ratio) != 0) return -1;
    d->model_payload = payload;
    d->model_ratio = ratio;
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

static double damping_ratio(const Instance *inst)
{
#ifdef HAS_VAR_damping_ratio
    return VALUE(inst, IDX_damping_ratio);
#else
    (void)inst;
    return 0.0;
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
    if (set_model(d, VALUE(inst, IDX_payload_mass), damping_ratio(inst)) != 0) {
        glue_log(inst, fmi2Error, "fmi2ExitInitializationMode: the modal damping matrix could not be built "
                 "(payload_mass = %g kg, damping_ratio = %g)", VALUE(inst, IDX_payload_mass), damping_ratio(inst));
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
    /* a restored FMU state of another instance may carry another payload or damping */
    int ok = set_model(d, VALUE(inst, IDX_payload_mass), damping_ratio(inst)) == 0;
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
