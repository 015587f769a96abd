/* SHA-256 (FIPS 180-4) of a buffer, as 64 lower-case hex digits (used to check the FMU's resources). */
#ifndef FLEXARM_SHA256_H
#define FLEXARM_SHA256_H
#include <stddef.h>
void sha256_hex(const unsigned char *data, size_t n, char out[65]);
#endif
