/*
 * NumPy's PCG64 bit generator (XSL-RR 128/64), seeded as numpy.random.PCG64(seed) seeds it (SeedSequence),
 * and Generator.random()'s conversion to a double in [0, 1). Portable C (128-bit arithmetic in 64-bit halves).
 */
#ifndef FLEXARM_PCG64_H
#define FLEXARM_PCG64_H
#include <stdint.h>

typedef struct {
    uint64_t state_hi, state_lo, inc_hi, inc_lo;
} Pcg64;

/* numpy.random.PCG64(seed) for an integer seed 0 <= seed < 2**64. */
void pcg64_seed(Pcg64 *rng, uint64_t seed);
uint64_t pcg64_next(Pcg64 *rng);
/* numpy.random.Generator.random(): (next >> 11) * 2**-53. */
double pcg64_random(Pcg64 *rng);
#endif
