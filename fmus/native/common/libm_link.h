/*
 * The C math library functions the models call that live in libm (not in libc) on Linux: fmax, fmin, sqrt,
 * hypot, pow, nearbyint, lround, remainder, copysign (the last two from the laws' generated C,
 * fmu_build/law_codegen.py, which includes this header too). A binary built from these sources by a tool that does not link libm (FMPy's
 * `fmpy compile`, whose CMake project links nothing but the sources) must still load in a host that has no
 * libm: every model source includes this header (through fmi2_glue.h), which routes those calls through
 * libm_link.c. There each function is the C library's whenever the process has one (on ELF platforms a weak
 * reference, so the same bits as before), else an own implementation (exact for fmax, fmin, nearbyint,
 * lround, copysign and remainder(x, 1), the only remainder the laws take; sqrt, hypot and pow within an ulp or so). The FMU's own binaries link libm and always use it.
 */
#ifndef FLEXARM_LIBM_LINK_H
#define FLEXARM_LIBM_LINK_H
#include <math.h>

double flexarm_fmax(double a, double b);
double flexarm_fmin(double a, double b);
double flexarm_sqrt(double x);
double flexarm_hypot(double a, double b);
double flexarm_pow(double x, double y);
double flexarm_nearbyint(double x);
long flexarm_lround(double x);
double flexarm_remainder(double x, double y);
double flexarm_copysign(double x, double s);

#ifndef FLEXARM_LIBM_LINK_IMPLEMENTATION
#define fmax flexarm_fmax
#define fmin flexarm_fmin
#define sqrt flexarm_sqrt
#define hypot flexarm_hypot
#define pow flexarm_pow
#define nearbyint flexarm_nearbyint
#define lround flexarm_lround
#define remainder flexarm_remainder
#define copysign flexarm_copysign
#endif
#endif
