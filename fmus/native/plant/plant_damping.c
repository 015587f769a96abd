/*
 * The native plant's modal damping matrix (flexarm.model.modal_damping_matrix): C_d from the flexible modes of the
 * arm at the damping configuration, built once per model (payload, damping ratio, link stiffness) by set_model in
 * plant.c.
 */
#include <math.h>
#include <string.h>

#include "fmi2_glue.h" /* its libm_link.h routes sqrt and fmax as in every model source */
#include "plant_linalg.h"
#include "plant_model.h"

/* -- modal damping (flexarm.model.modal_damping_matrix) -------------------------------------------- */
/* C_d = M Φ diag(2ζω_k) Φᵀ M over the flexible modes at the damping configuration, Φ mass-normalised:
   with M = L Lᵀ and the symmetric eigenproblem of L⁻¹ K_t L⁻ᵀ = Y Λ Yᵀ, M Φ = L Y. */
int build_damping(PlantData *d, double ratio)
{
    d->damped = 0;
    memset(d->damping, 0, sizeof d->damping);
    if (ratio == 0.0) return 0;
    double z[NZ] = {0}, zero[N] = {0}, acc[N], q[N * N], v[N * N], mass[N * N], kt[N * N], a[N * N], y[N * N],
           lam[N], lower[N * N];
    Eval ev;
    for (int i = 0; i < N; i++) z[i] = PLANT_DAMPING_Q1 + (i >= PLANT_JOINT2_DISTAL ? PLANT_DAMPING_Q2 : 0.0);
    if (evaluate(d, z, &ev) != 0) return -1;
    mass_full(&ev, mass);
    acceleration(d, &ev, zero, acc);
    tangents(d, &ev, zero, acc, q, v);
    double qm[N * N];
    memcpy(qm, q, sizeof qm);
    for (int j = 0; j < N; j++) mass_solve(d, &ev, qm + j * N, q + j * N); /* A_θ = M⁻¹ Q, column-major */
    for (int i = 0; i < N; i++) /* K_t = −M A_θ, row-major */
        for (int j = 0; j < N; j++) {
            double t = 0.0;
            for (int k = 0; k < N; k++) t += mass[i * N + k] * q[j * N + k];
            kt[i * N + j] = -t;
        }
    double low[N * N]; /* M = L Lᵀ */
    memcpy(low, mass, sizeof low);
    if (chol_factor(low, N) != 0) return -1;
    for (int i = 0; i < N; i++) /* symmetric part, its columns (= rows) solved with L: L⁻¹ K */
        for (int j = 0; j < N; j++) a[j * N + i] = 0.5 * (kt[i * N + j] + kt[j * N + i]);
    for (int j = 0; j < N; j++) chol_forward(low, a + j * N, N);
    for (int i = 0; i < N; i++) /* (L⁻¹ K)ᵀ's columns solved again: L⁻¹ K L⁻ᵀ */
        for (int j = 0; j < N; j++) y[i * N + j] = a[j * N + i];
    for (int j = 0; j < N; j++) chol_forward(low, y + j * N, N);
    for (int i = 0; i < N; i++)
        for (int j = 0; j < N; j++) a[i * N + j] = 0.5 * (y[i * N + j] + y[j * N + i]);
    if (sym_eigen(a, lam, y, N) != 0) return -1;
    for (int i = 0; i < N; i++) /* L, row-major */
        for (int j = 0; j < N; j++) lower[i * N + j] = j <= i ? low[j * N + i] : 0.0;
    double mphi[N * N], scaled[N * N]; /* M Φ = L Y; (M Φ diag(2ζω)) */
    mat_mul(lower, y, mphi, N);
    for (int i = 0; i < N; i++)
        for (int k = 0; k < N; k++)
            scaled[i * N + k] = k < 2 ? 0.0 : mphi[i * N + k] * (2.0 * ratio * sqrt(fmax(lam[k], 0.0)));
    double full[N * N]; /* the two smallest (rigid-body) modes dropped above */
    for (int i = 0; i < N; i++)
        for (int j = 0; j < N; j++) {
            double t = 0.0;
            for (int k = 2; k < N; k++) t += scaled[i * N + k] * mphi[j * N + k];
            full[i * N + j] = t;
        }
    for (int i = 0; i < N; i++)
        for (int j = 0; j < N; j++) d->damping[i * N + j] = 0.5 * (full[i * N + j] + full[j * N + i]);
    d->damped = 1;
    return 0;
}
