/* NumPy's PCG64 and SeedSequence (numpy/random/src/pcg64, numpy/random/bit_generator.pyx). */
#include "pcg64.h"

/* 64 x 64 -> 128 */
static void mul64(uint64_t a, uint64_t b, uint64_t *hi, uint64_t *lo)
{
    uint64_t a0 = a & 0xffffffffu, a1 = a >> 32, b0 = b & 0xffffffffu, b1 = b >> 32;
    uint64_t p00 = a0 * b0, p01 = a0 * b1, p10 = a1 * b0, p11 = a1 * b1;
    uint64_t mid = (p00 >> 32) + (p01 & 0xffffffffu) + (p10 & 0xffffffffu);
    *lo = (p00 & 0xffffffffu) | (mid << 32);
    *hi = p11 + (p01 >> 32) + (p10 >> 32) + (mid >> 32);
}

/* state = state * MULT + inc (mod 2**128) */
static void step(Pcg64 *r)
{
    const uint64_t mult_hi = 2549297995355413924ull, mult_lo = 4865540595714422341ull;
    uint64_t hi, lo;
    mul64(r->state_lo, mult_lo, &hi, &lo);
    hi += r->state_lo * mult_hi + r->state_hi * mult_lo;
    uint64_t new_lo = lo + r->inc_lo;
    hi += r->inc_hi + (new_lo < lo);
    r->state_hi = hi;
    r->state_lo = new_lo;
}

uint64_t pcg64_next(Pcg64 *r)
{
    step(r);
    uint64_t x = r->state_hi ^ r->state_lo;
    unsigned rot = (unsigned)(r->state_hi >> 58);
    return (x >> rot) | (x << ((64u - rot) & 63u));
}

double pcg64_random(Pcg64 *r)
{
    return (double)(pcg64_next(r) >> 11) * (1.0 / 9007199254740992.0);
}

/* SeedSequence(seed).generate_state(4, uint64), pool size 4. */
static void seed_sequence(uint64_t seed, uint64_t out[4])
{
    const uint32_t INIT_A = 0x43b0d7e5u, MULT_A = 0x931e8875u, INIT_B = 0x8b51f9ddu, MULT_B = 0x58f38dedu;
    const uint32_t MIX_MULT_L = 0xca01f9ddu, MIX_MULT_R = 0x4973f715u;
    uint32_t entropy[2];
    int n_entropy = 0;
    do { /* the integer as little-endian 32-bit words (0 -> one word) */
        entropy[n_entropy++] = (uint32_t)(seed & 0xffffffffu);
        seed >>= 32;
    } while (seed != 0);
    uint32_t pool[4], hash_const = INIT_A;
#define HASHMIX(value, result)                 \
    do {                                       \
        uint32_t v_ = (value) ^ hash_const;    \
        hash_const *= MULT_A;                  \
        v_ *= hash_const;                      \
        v_ ^= v_ >> 16;                        \
        (result) = v_;                         \
    } while (0)
#define MIX(x, y, result)                                  \
    do {                                                   \
        uint32_t r_ = MIX_MULT_L * (x) - MIX_MULT_R * (y); \
        r_ ^= r_ >> 16;                                    \
        (result) = r_;                                     \
    } while (0)
    for (int i = 0; i < 4; i++) HASHMIX(i < n_entropy ? entropy[i] : 0u, pool[i]);
    for (int src = 0; src < 4; src++)
        for (int dst = 0; dst < 4; dst++)
            if (src != dst) {
                uint32_t h;
                HASHMIX(pool[src], h);
                MIX(pool[dst], h, pool[dst]);
            }
    /* entropy beyond the pool size: none (at most two words) */
    uint32_t words[8];
    hash_const = INIT_B;
    for (int i = 0; i < 8; i++) {
        uint32_t v = pool[i % 4] ^ hash_const;
        hash_const *= MULT_B;
        v *= hash_const;
        v ^= v >> 16;
        words[i] = v;
    }
#undef HASHMIX
#undef MIX
    for (int i = 0; i < 4; i++) out[i] = (uint64_t)words[2 * i] | ((uint64_t)words[2 * i + 1] << 32);
}

void pcg64_seed(Pcg64 *r, uint64_t seed)
{
    uint64_t v[4];
    seed_sequence(seed, v);
    /* pcg64_set_seed(state, seed = (v0 << 64 | v1), inc = (v2 << 64 | v3)): pcg_setseq_128_srandom_r */
    r->state_hi = 0, r->state_lo = 0;
    r->inc_hi = (v[2] << 1) | (v[3] >> 63);
    r->inc_lo = (v[3] << 1) | 1u;
    step(r);
    uint64_t lo = r->state_lo + v[1];
    r->state_hi += v[0] + (lo < r->state_lo);
    r->state_lo = lo;
    step(r);
}
