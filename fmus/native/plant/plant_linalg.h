/*
 * Small dense linear algebra of the native plant (n = 11, and 23 for the exponential scheme), as
 * flexarm._kernels: the same operations in the same order for every element, arranged so that
 * independent elements are computed side by side (the compiler may then use SIMD; no reassociation,
 * -ffp-contract=off), which keeps every platform's bits equal.
 */
#ifndef FLEXARM_PLANT_LINALG_H
#define FLEXARM_PLANT_LINALG_H

/* Lower Cholesky factor in place of the symmetric positive definite n×n `a`, stored column-major
   (a[j n + i] = A_ij; only i >= j is read and written). -1 if `a` is not positive definite. */
int chol_factor(double *a, int n);
/* Solve L x = b in place (forward substitution only), L from chol_factor. */
void chol_forward(const double *low, double *x, int n);
/* Solve (L Lᵀ) x = b in place, L from chol_factor. */
void chol_solve(const double *low, double *x, int n);

/* LU factors with partial pivoting of the row-major n×n `lu`, in place; -1 if singular. */
int lu_factor(double *lu, int *piv, int n);
/* Solve with lu_factor's factors: x = A⁻¹ b (x and b distinct). */
void lu_solve(const double *lu, const int *piv, const double *b, double *x, int n);

/* C = A B, row-major n×n (C distinct from A and B). */
void mat_mul(const double *a, const double *b, double *c, int n);

/* Eigenvalues (ascending) and orthonormal eigenvectors (columns of `vec`, row-major n×n) of the symmetric
   row-major `a` (destroyed), cyclic Jacobi rotations. -1 if it did not converge. */
int sym_eigen(double *a, double *val, double *vec, int n);

/* Matrix exponential of the row-major n×n `a` (n <= 23) into `e`: scaling and squaring with the [13/13]
   Padé approximant, as flexarm._kernels.expm (Higham 2005). -1 if the Padé denominator is singular. */
int expm(const double *a, double *e, int n);

#endif
