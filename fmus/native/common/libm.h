/*
 * The few definitions musl's trigonometric kernels (__sin.c, __cos.c, __tan.c, __rem_pio2.c, __rem_pio2_large.c,
 * copied from the ziglang package into each FMU's sources at build time, MIT licence: musl_COPYRIGHT.txt)
 * need from musl's internal libm.h, under names of our own so they never clash with the C library's.
 */
#ifndef FLEXARM_MUSL_LIBM_H
#define FLEXARM_MUSL_LIBM_H
#include <float.h>
#include <math.h>
#include <stdint.h>

/* the word access macros of musl's libm.h */
#define GET_HIGH_WORD(hi, d)                            \
    do {                                                \
        union {double f; uint64_t i;} u_ = {(d)};       \
        (hi) = (uint32_t)(u_.i >> 32);                  \
    } while (0)
#define SET_LOW_WORD(d, lo)                             \
    do {                                                \
        union {double f; uint64_t i;} u_ = {(d)};       \
        u_.i &= 0xffffffff00000000ull;                  \
        u_.i |= (uint32_t)(lo);                         \
        (d) = u_.f;                                     \
    } while (0)
#define hidden
#define predict_false(x) (x)
#define __sin flexarm_musl_sin
#define __cos flexarm_musl_cos
#define __rem_pio2 flexarm_musl_rem_pio2
#define __tan flexarm_musl_tan
#define __rem_pio2_large flexarm_musl_rem_pio2_large

double __sin(double x, double y, int iy);
double __cos(double x, double y);
int __rem_pio2(double x, double *y);
double __tan(double x, double y, int odd);
int __rem_pio2_large(double *x, double *y, int e0, int nx, int prec);
#endif
