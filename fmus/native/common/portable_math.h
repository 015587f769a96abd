/*
 * sin, cos, exp and log1p computed by the FMU's own code (musl's kernels), not the platform's C library, so that
 * linux64, win64 and darwin64 binaries give the same bits (C libraries differ in the last bit, and the
 * arm's stiff bracket modes amplify such differences in the accelerations).
 */
#ifndef FLEXARM_PORTABLE_MATH_H
#define FLEXARM_PORTABLE_MATH_H
double flexarm_sin(double x);
double flexarm_cos(double x);
double flexarm_tan(double x);
/* sin x and cos x together (one argument reduction), bit for bit flexarm_sin and flexarm_cos */
void flexarm_sincos(double x, double *sin_x, double *cos_x);
/* e^x and log(1 + x), the same bits on every platform (within 1 ulp of the exact value) */
double flexarm_exp(double x);
double flexarm_log1p(double x);
#endif
