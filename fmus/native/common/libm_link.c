/* See libm_link.h: libm's functions when the process has libm, own ones when it has not. */
#define FLEXARM_LIBM_LINK_IMPLEMENTATION
#include "libm_link.h"

#include <stdint.h>

#include "portable_math.h"

#if defined(__ELF__)
/* Weak references: resolved to libm's functions when libm is in the process (the FMU's own binaries link it;
   most hosts have it), NULL otherwise, and the library still loads. */
#pragma weak fmax
#pragma weak fmin
#pragma weak sqrt
#pragma weak hypot
#pragma weak pow
#pragma weak nearbyint
#pragma weak lround
#pragma weak remainder
#define HAVE(f) ((f) != 0)
#else
#define HAVE(f) 1 /* Windows and macOS: the math functions are in the C runtime every process has */
#endif

static int is_nan(double x) { return x != x; }

static double abs_(double x)
{
    union {double f; uint64_t i;} u = {x};
    u.i &= ~(1ull << 63);
    return u.f;
}

static double with_sign_of(double x, double s)
{
    union {double f; uint64_t i;} ux = {x}, us = {s};
    ux.i = (ux.i & ~(1ull << 63)) | (us.i & (1ull << 63));
    return ux.f;
}

double flexarm_fmax(double a, double b)
{
    if (HAVE(fmax)) return fmax(a, b);
    if (is_nan(a)) return b;
    if (is_nan(b)) return a;
    if (a == b) return with_sign_of(1.0, a) > 0 ? a : b; /* fmax(-0, +0) = +0 */
    return a > b ? a : b;
}

double flexarm_fmin(double a, double b)
{
    if (HAVE(fmin)) return fmin(a, b);
    if (is_nan(a)) return b;
    if (is_nan(b)) return a;
    if (a == b) return with_sign_of(1.0, a) < 0 ? a : b; /* fmin(-0, +0) = -0 */
    return a < b ? a : b;
}

double flexarm_nearbyint(double x)
{
    if (HAVE(nearbyint)) return nearbyint(x);
    if (!(abs_(x) < 0x1p52)) return x; /* already an integer, inf or NaN */
    double r = abs_(x) + 0x1p52 - 0x1p52; /* rounds to nearest, ties to even (the default mode) */
    return with_sign_of(r, x);
}

double flexarm_copysign(double x, double s)
{
    return with_sign_of(x, s); /* a bit operation: no library needed */
}

double flexarm_remainder(double x, double y)
{
    if (HAVE(remainder)) return remainder(x, y);
    if (y == 1.0) return x - flexarm_nearbyint(x); /* exact: the quotient rounded half to even (IEEE 754) */
    return x - y * flexarm_nearbyint(x / y);    /* other divisors: not exact (the laws take none) */
}

long flexarm_lround(double x)
{
    if (HAVE(lround)) return lround(x);
    double a = abs_(x);
    long t = (long)a; /* truncation; |x| below 2**63 as lround requires */
    if (a - (double)t >= 0.5) t += 1; /* a - t is exact below 2**52: halfway rounds away from zero */
    return x < 0 ? -t : t;
}

double flexarm_sqrt(double x)
{
    if (HAVE(sqrt)) return sqrt(x);
    if (is_nan(x) || x < 0) return (x - x) / (x - x);
    if (x == 0 || x == 1.0 / 0.0) return x;
    union {double f; uint64_t i;} u = {x};
    u.i = (u.i >> 1) + (0x3ffull << 51); /* a first guess within a factor of 2 */
    double y = u.f;
    for (int i = 0; i < 8; i++) y = 0.5 * (y + x / y); /* Newton: quadratic convergence */
    return y;
}

double flexarm_hypot(double a, double b)
{
    if (HAVE(hypot)) return hypot(a, b);
    a = abs_(a);
    b = abs_(b);
    if (a == 1.0 / 0.0 || b == 1.0 / 0.0) return 1.0 / 0.0;
    if (is_nan(a) || is_nan(b)) return a + b;
    double m = a > b ? a : b, s = a > b ? b : a;
    if (m == 0) return 0;
    double r = s / m;
    return m * flexarm_sqrt(1.0 + r * r);
}

double flexarm_pow(double x, double y)
{
    if (HAVE(pow)) return pow(x, y);
    if (y == 0) return 1.0;
    if (abs_(y) < 0x1p31 && (double)(long)y == y) { /* an integer power: by squaring */
        long n = (long)abs_(y);
        double r = 1.0, p = x;
        for (; n; n >>= 1, p *= p)
            if (n & 1) r *= p;
        return y < 0 ? 1.0 / r : r;
    }
    if (x < 0) return (x - x) / (x - x);
    return flexarm_exp(y * flexarm_log1p(x - 1.0));
}
