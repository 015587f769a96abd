/* sin, cos and tan from musl's kernels (the argument reduction and quadrant logic of musl's sin.c, cos.c, tan.c). */
#include "portable_math.h"

#include <stdint.h>
#include <string.h>

#include "libm.h"

static uint32_t high_word(double x)
{
    uint64_t bits;
    memcpy(&bits, &x, sizeof bits);
    return (uint32_t)(bits >> 32) & 0x7fffffffu;
}

double flexarm_sin(double x)
{
    double y[2];
    uint32_t ix = high_word(x);
    if (ix <= 0x3fe921fb) {             /* |x| ~< pi/4 */
        if (ix < 0x3e500000) return x;  /* |x| < 2**-26 */
        return __sin(x, 0.0, 0);
    }
    if (ix >= 0x7ff00000) return x - x; /* inf or nan */
    unsigned n = (unsigned)__rem_pio2(x, y);
    switch (n & 3) {
    case 0: return __sin(y[0], y[1], 1);
    case 1: return __cos(y[0], y[1]);
    case 2: return -__sin(y[0], y[1], 1);
    default: return -__cos(y[0], y[1]);
    }
}

double flexarm_cos(double x)
{
    double y[2];
    uint32_t ix = high_word(x);
    if (ix <= 0x3fe921fb) {
        if (ix < 0x3e46a09e) return 1.0; /* |x| < 2**-27 * sqrt(2) */
        return __cos(x, 0.0);
    }
    if (ix >= 0x7ff00000) return x - x;
    unsigned n = (unsigned)__rem_pio2(x, y);
    switch (n & 3) {
    case 0: return __cos(y[0], y[1]);
    case 1: return -__sin(y[0], y[1], 1);
    case 2: return -__cos(y[0], y[1]);
    default: return __sin(y[0], y[1], 1);
    }
}

double flexarm_tan(double x)
{
    double y[2];
    uint32_t ix = high_word(x);
    if (ix <= 0x3fe921fb) {
        if (ix < 0x3e400000) return x; /* |x| < 2**-27 */
        return __tan(x, 0.0, 0);
    }
    if (ix >= 0x7ff00000) return x - x;
    unsigned n = (unsigned)__rem_pio2(x, y);
    return __tan(y[0], y[1], (int)(n & 1));
}

void flexarm_sincos(double x, double *sin_x, double *cos_x)
{
    /* flexarm_sin and flexarm_cos with one argument reduction: the same bits as the two calls */
    double y[2];
    uint32_t ix = high_word(x);
    if (ix <= 0x3fe921fb) {
        *sin_x = ix < 0x3e500000 ? x : __sin(x, 0.0, 0);
        *cos_x = ix < 0x3e46a09e ? 1.0 : __cos(x, 0.0);
        return;
    }
    if (ix >= 0x7ff00000) {
        *sin_x = *cos_x = x - x;
        return;
    }
    unsigned n = (unsigned)__rem_pio2(x, y);
    const double s = __sin(y[0], y[1], 1), c = __cos(y[0], y[1]);
    switch (n & 3) {
    case 0: *sin_x = s; *cos_x = c; break;
    case 1: *sin_x = c; *cos_x = -s; break;
    case 2: *sin_x = -s; *cos_x = -c; break;
    default: *sin_x = -c; *cos_x = s; break;
    }
}

/* exp and log1p: musl's (FreeBSD's msun) algorithms, as ported in the ziglang package (compiler_rt/exp.zig,
   std/math/log1p.zig; MIT licence), with the reduction constants of fdlibm. Within 1 ulp of the correctly
   rounded value, and the same bits on every platform. */
double flexarm_exp(double x)
{
    static const double half[2] = {0.5, -0.5}, ln2hi = 6.93147180369123816490e-01,
                        ln2lo = 1.90821492927058770002e-10, invln2 = 1.44269504088896338700e+00,
                        P1 = 1.66666666666666019037e-01, P2 = -2.77777777770155933842e-03,
                        P3 = 6.61375632143793436117e-05, P4 = -1.65339022054652515390e-06,
                        P5 = 4.13813679705723846039e-08;
    uint64_t bits;
    memcpy(&bits, &x, sizeof bits);
    uint32_t hx = (uint32_t)(bits >> 32);
    int sign = (int)(hx >> 31), k;
    hx &= 0x7fffffffu;
    if (x != x) return x;
    if (hx >= 0x4086232Bu) { /* |x| >= 708.39 or nan */
        if (hx > 0x7ff00000u) return x;
        if (x > 709.782712893383973096) return HUGE_VAL;
        if (x < -745.13321910194110842) return 0.0;
    }
    double hi, lo;
    if (hx > 0x3FD62E42u) {      /* |x| > 0.5 ln2 */
        if (hx > 0x3FF0A2B2u) k = (int)(invln2 * x + half[sign]); /* |x| >= 1.5 ln2 */
        else k = 1 - sign - sign;
        hi = x - k * ln2hi;
        lo = k * ln2lo;
        x = hi - lo;
    } else if (hx > 0x3E300000u) { /* |x| > 2^-28 */
        k = 0, hi = x, lo = 0.0;
    } else {
        return 1.0 + x;
    }
    double xx = x * x, c = x - xx * (P1 + xx * (P2 + xx * (P3 + xx * (P4 + xx * P5)))),
           y = 1.0 + (x * c / (2.0 - c) - lo + hi);
    return k == 0 ? y : ldexp(y, k);
}

double flexarm_log1p(double x)
{
    static const double ln2_hi = 6.93147180369123816490e-01, ln2_lo = 1.90821492927058770002e-10,
                        Lg1 = 6.666666666666735130e-01, Lg2 = 3.999999999940941908e-01,
                        Lg3 = 2.857142874366239149e-01, Lg4 = 2.222219843214978396e-01,
                        Lg5 = 1.818357216161805012e-01, Lg6 = 1.531383769920937332e-01,
                        Lg7 = 1.479819860511658591e-01;
    uint64_t ix;
    memcpy(&ix, &x, sizeof ix);
    uint32_t hx = (uint32_t)(ix >> 32);
    int k = 1;
    double c = 0.0, f = 0.0;
    if (hx < 0x3FDA827Au || hx >> 31) { /* 1 + x < sqrt(2) */
        if (ix == 0xBFF0000000000000ull) return -HUGE_VAL; /* log1p(-1) */
        if (hx >= 0xBFF00000u) return (x - x) / (x - x);  /* x < -1: nan */
        if ((hx << 1) < (0x3CA00000u << 1)) return x;      /* |x| < 2^-53 */
        if (hx <= 0xBFD2BEC4u) k = 0, c = 0.0, f = x;      /* sqrt(2)/2 <= 1 + x < sqrt(2) */
    } else if (hx >= 0x7ff00000u) {
        return x;
    }
    if (k != 0) {
        double uf = 1.0 + x;
        uint64_t hu;
        memcpy(&hu, &uf, sizeof hu);
        uint32_t iu = (uint32_t)(hu >> 32) + (0x3ff00000u - 0x3fe6a09eu);
        k = (int)(iu >> 20) - 0x3ff;
        if (k < 54) { /* correction term of the rounding in 1 + x */
            c = k >= 2 ? 1.0 - (uf - x) : x - (uf - 1.0);
            c /= uf;
        } else {
            c = 0.0;
        }
        iu = (iu & 0x000fffffu) + 0x3fe6a09eu; /* 1 + x scaled into [sqrt(2)/2, sqrt(2)] */
        uint64_t iq = (uint64_t)iu << 32 | (hu & 0xffffffffull);
        memcpy(&f, &iq, sizeof f);
        f -= 1.0;
    }
    double hfsq = 0.5 * f * f, s = f / (2.0 + f), z = s * s, w = z * z,
           t1 = w * (Lg2 + w * (Lg4 + w * Lg6)), t2 = z * (Lg1 + w * (Lg3 + w * (Lg5 + w * Lg7))), R = t2 + t1,
           dk = k;
    return s * (hfsq + R) + (dk * ln2_lo + c) - hfsq + f + dk * ln2_hi;
}
