/*
 * The native plant's integration schemes over one substep, the numerical methods of flexarm._integrator_kernels
 * with the same coefficients and tolerances: RODAS4 with the reduced stage system and its embedded error
 * estimate, the exponential Rosenbrock-Euler step, 2-stage Gauss-Legendre collocation with simplified Newton, and
 * the RK4 reference. plant.c chooses the scheme, the substeps and the error control of a communication step.
 */
#include <math.h>
#include <string.h>

#include "fmi2_glue.h" /* its libm_link.h routes sqrt and fmax as in every model source */
#include "flexarm_physics.h"
#include "plant_constants.h"
#include "plant_linalg.h"
#include "plant_model.h"
#include "portable_math.h"

static void stage_solve(PlantData *d, const double *lu, const int *piv, const double *b, double *x)
{
    double bp[N];
    for (int i = 0; i < N; i++) bp[i] = b[piv[i]];
    const double *arg[2] = {lu, bp};
    double *res[1] = {x};
    flexarm_lu_solve(arg, res, d->iw, d->w, 0);
}

/* Q and V − C_d (column-major) at the state of `ev` with rates omega and accelerations acc. */

/* -- RODAS4 (flexarm._integrator_kernels._rodas4_step_loops) -------------------------------------- */
/* One step of size h from z, whose evaluation is `ev0`; `ev` is workspace. -1 if a matrix is singular. */
int rodas4_step(PlantData *d, const double *z, const Eval *ev0, Eval *ev, const double *forces, double h,
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
int exponential_step(PlantData *d, const double *z, const Eval *ev0, const double *forces, double h,
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
int gauss_step(PlantData *d, const double *z, const Eval *ev0, Eval *ev, const double *forces, double h,
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
int rk4_steps(PlantData *d, const double *z, Eval *ev, const double *forces, double h, int steps,
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
