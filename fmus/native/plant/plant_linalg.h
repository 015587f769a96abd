/*
 * Small dense linear algebra of the native plant (n = 11, and 23 for the exponential scheme), as
 * flexarm._kernels (the n = 11 factorisation and solves of every stage are generated straight-line code
 * instead: fmu_build/native_codegen.py), arranged for short dependency chains: independent elements are computed side
 * by side (the compiler may use SIMD; no reassociation, -ffp-contract=off), so every platform gives
 * the same bits. Header-only and static so that the compiler inlines the hot ones with n known.
 * Included by plant.c only.
 */
#ifndef FLEXARM_PLANT_LINALG_H
#define FLEXARM_PLANT_LINALG_H

#include <math.h>
#include <string.h>

#include "plant_constants.h"

#define NMAX 23

/* Lower Cholesky factor L (M = L Lᵀ) in place, column-major as ldl_factor; -1 if not positive definite. */
static int chol_factor(double *a, int n)
{
    for (int j = 0; j < n; j++) {
        double *col = a + j * n;
        for (int k = 0; k < j; k++) {
            const double *lk = a + k * n;
            const double ljk = lk[j];
            for (int i = j; i < n; i++) col[i] -= lk[i] * ljk;
        }
        if (!(col[j] > 0.0)) return -1;
        const double dj = sqrt(col[j]);
        col[j] = dj;
        for (int i = j + 1; i < n; i++) col[i] /= dj;
    }
    return 0;
}

/* Solve L x = b in place (forward substitution), L from chol_factor. */
static void chol_forward(const double *low, double *x, int n)
{
    for (int k = 0; k < n; k++) {
        const double *lk = low + k * n;
        x[k] /= lk[k];
        const double xk = x[k];
        for (int i = k + 1; i < n; i++) x[i] -= lk[i] * xk;
    }
}

/* LU factors with partial pivoting of the row-major n×n `lu`, in place (1/U_kk on the diagonal); -1 if
   singular. */
static inline int lu_factor(double *lu, int *piv, int n)
{
    for (int i = 0; i < n; i++) piv[i] = i;
    for (int k = 0; k < n; k++) {
        int p = k;
        double big = fabs(lu[k * n + k]);
        for (int i = k + 1; i < n; i++)
            if (fabs(lu[i * n + k]) > big) big = fabs(lu[i * n + k]), p = i;
        if (big == 0.0) return -1;
        if (p != k) {
            for (int j = 0; j < n; j++) {
                double t = lu[k * n + j];
                lu[k * n + j] = lu[p * n + j];
                lu[p * n + j] = t;
            }
            int t = piv[k];
            piv[k] = piv[p];
            piv[p] = t;
        }
        double *rk = lu + k * n;
        const double inv = 1.0 / rk[k];
        for (int i = k + 1; i < n; i++) {
            double *ri = lu + i * n;
            ri[k] *= inv;
            const double f = ri[k];
            for (int j = k + 1; j < n; j++) ri[j] -= f * rk[j];
        }
        rk[k] = inv; /* the solves multiply: no division on their critical path */
    }
    return 0;
}

/* Solve with lu_factor's factors: x = A⁻¹ b (x and b distinct). */
static inline void lu_solve(const double *lu, const int *piv, const double *b, double *x, int n)
{
    for (int i = 0; i < n; i++) x[i] = b[piv[i]];
    for (int k = 0; k < n; k++) { /* unit lower: x_i −= L_ik x_k, k ascending */
        const double xk = x[k];
        for (int i = k + 1; i < n; i++) x[i] -= lu[i * n + k] * xk;
    }
    for (int i = n - 1; i >= 0; i--) {
        const double *ri = lu + i * n;
        double t = x[i];
        for (int k = n - 1; k > i; k--) t -= ri[k] * x[k];
        x[i] = t * ri[i];
    }
}

/* C = A B, row-major n×n (C distinct from A and B). */
static void mat_mul(const double *a, const double *b, double *c, int n)
{
    for (int i = 0; i < n; i++) {
        double *ci = c + i * n;
        for (int j = 0; j < n; j++) ci[j] = 0.0;
        for (int k = 0; k < n; k++) {
            const double aik = a[i * n + k];
            const double *bk = b + k * n;
            for (int j = 0; j < n; j++) ci[j] += aik * bk[j];
        }
    }
}

/* Eigenvalues (ascending) and orthonormal eigenvectors (columns of `vec`, row-major n×n) of the symmetric
   row-major `a` (destroyed), cyclic Jacobi rotations. -1 if it did not converge. */
static int sym_eigen(double *a, double *val, double *vec, int n)
{
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) vec[i * n + j] = i == j ? 1.0 : 0.0;
    int converged = 0;
    for (int sweep = 0; sweep < 100 && !converged; sweep++) {
        converged = 1;
        for (int p = 0; p < n - 1; p++)
            for (int q = p + 1; q < n; q++) {
                const double apq = a[p * n + q], app = a[p * n + p], aqq = a[q * n + q];
                /* negligible beside the diagonal (relative criterion: keeps the small eigenvalues accurate) */
                if (fabs(apq) <= 0x1p-53 * sqrt(fabs(app)) * sqrt(fabs(aqq))) {
                    a[p * n + q] = a[q * n + p] = 0.0;
                    continue;
                }
                converged = 0;
                const double tau = (aqq - app) / (2.0 * apq);
                const double t = fabs(tau) > 1e150 ? 0.5 / tau
                                                   : (tau >= 0.0 ? 1.0 : -1.0) / (fabs(tau) + sqrt(1.0 + tau * tau));
                const double c = 1.0 / sqrt(1.0 + t * t), s = t * c;
                for (int k = 0; k < n; k++) { /* A J (columns p, q) */
                    const double akp = a[k * n + p], akq = a[k * n + q];
                    a[k * n + p] = c * akp - s * akq;
                    a[k * n + q] = s * akp + c * akq;
                }
                for (int k = 0; k < n; k++) { /* Jᵀ A (rows p, q) */
                    const double apk = a[p * n + k], aqk = a[q * n + k];
                    a[p * n + k] = c * apk - s * aqk;
                    a[q * n + k] = s * apk + c * aqk;
                }
                for (int k = 0; k < n; k++) {
                    const double vkp = vec[k * n + p], vkq = vec[k * n + q];
                    vec[k * n + p] = c * vkp - s * vkq;
                    vec[k * n + q] = s * vkp + c * vkq;
                }
            }
    }
    if (!converged) return -1;
    for (int i = 0; i < n; i++) val[i] = a[i * n + i];
    for (int i = 1; i < n; i++) /* ascending, vectors along (insertion sort, n small) */
        for (int j = i; j > 0 && val[j - 1] > val[j]; j--) {
            double t = val[j];
            val[j] = val[j - 1];
            val[j - 1] = t;
            for (int k = 0; k < n; k++) {
                t = vec[k * n + j];
                vec[k * n + j] = vec[k * n + j - 1];
                vec[k * n + j - 1] = t;
            }
        }
    return 0;
}

/* Matrix exponential of the row-major n×n `a` (n <= NMAX) into `e`: scaling and squaring with the [13/13]
   Padé approximant, as flexarm._kernels.expm (Higham 2005). -1 if the Padé denominator is singular. */
static int expm(const double *a, double *e, int n)
{
    double x[NMAX * NMAX], x2[NMAX * NMAX], x4[NMAX * NMAX], x6[NMAX * NMAX], t[NMAX * NMAX], u[NMAX * NMAX],
        v[NMAX * NMAX], w[NMAX * NMAX], col[NMAX], sol[NMAX]; /* 34 KB of stack */
    if (n > NMAX) return -1;
    const double *b = EXPM_PADE13;
    const int nn = n * n;
    double norm = 0.0;
    for (int j = 0; j < n; j++) {
        double s = 0.0;
        for (int i = 0; i < n; i++) s += fabs(a[i * n + j]);
        norm = fmax(norm, s);
    }
    int squarings = 0; /* ceil(log2(norm / θ13)) by exact halvings */
    for (double r = norm / EXPM_THETA13; r > 1.0; r *= 0.5) squarings++;
    double scale = 1.0;
    for (int k = 0; k < squarings; k++) scale *= 0.5;
    for (int k = 0; k < nn; k++) x[k] = a[k] * scale;
    mat_mul(x, x, x2, n);
    mat_mul(x2, x2, x4, n);
    mat_mul(x4, x2, x6, n);
    for (int k = 0; k < nn; k++) t[k] = b[13] * x6[k] + b[11] * x4[k] + b[9] * x2[k];
    mat_mul(x6, t, w, n);
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) {
            const int k = i * n + j;
            t[k] = w[k] + b[7] * x6[k] + b[5] * x4[k] + b[3] * x2[k] + b[1] * (i == j ? 1.0 : 0.0);
        }
    mat_mul(x, t, u, n);
    for (int k = 0; k < nn; k++) t[k] = b[12] * x6[k] + b[10] * x4[k] + b[8] * x2[k];
    mat_mul(x6, t, w, n);
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) {
            const int k = i * n + j;
            v[k] = w[k] + b[6] * x6[k] + b[4] * x4[k] + b[2] * x2[k] + b[0] * (i == j ? 1.0 : 0.0);
        }
    /* r = (v − u)⁻¹ (v + u) */
    int piv[NMAX];
    for (int k = 0; k < nn; k++) {
        t[k] = v[k] - u[k];
        w[k] = v[k] + u[k];
    }
    if (lu_factor(t, piv, n) != 0) return -1;
    for (int j = 0; j < n; j++) {
        for (int i = 0; i < n; i++) col[i] = w[i * n + j];
        lu_solve(t, piv, col, sol, n);
        for (int i = 0; i < n; i++) e[i * n + j] = sol[i];
    }
    for (int k = 0; k < squarings; k++) {
        mat_mul(e, e, w, n);
        memcpy(e, w, (size_t)nn * sizeof *e);
    }
    return 0;
}

#endif
