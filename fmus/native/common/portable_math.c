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
