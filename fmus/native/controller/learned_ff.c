/*
 * The learned feedforward correction of the controller FMUs (flexarm.ilc design files), read at initialisation
 * from the FMU's resources (LEARNED_FF_RESOURCE, flexarm.ilc.LEARNED_RESOURCE, packed by
 * fmu_build/learned.py): the .npz (numpy savez, stored, array correction of shape (m, 2), little-endian doubles)
 * and its .json beside it, which must record the npz's SHA-256 and the SHA-256 of
 * the trajectory and parameter files the FMU was built from, and whose own seal (json_sha256, the SHA-256 of the
 * .json's bytes with the seal written as 64 zeros, flexarm.provenance.sealed_json_text) must hold: a stale or
 * edited file is refused, as flexarm.ilc.read_learned_feedforward refuses it. Shared by controller.c and
 * controller_lqg.c.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_glue.h"
#include "learned_ff.h"
#include "learned_ff_data.h"
#include "sha256.h"

/* The string value of "key": "value" in a JSON text into out (size 80); 0 if found. */
static int json_string(const char *json, const char *key, char *out)
{
    char pattern[64];
    snprintf(pattern, sizeof pattern, "\"%s\"", key);
    const char *p = strstr(json, pattern);
    if (p == NULL) return -1;
    p += strlen(pattern);
    while (*p == ' ' || *p == ':') p++;
    if (*p++ != '"') return -1;
    size_t n = 0;
    while (p[n] && p[n] != '"' && n < 79) n++;
    if (p[n] != '"') return -1;
    memcpy(out, p, n);
    out[n] = '\0';
    return 0;
}

/* The seal of a sealed JSON text (flexarm.provenance.read_sealed_json): exactly one "json_sha256": "<64 hex>",
 * equal to the SHA-256 of the text with those 64 characters written as zeros. 0 if it holds. */
static int json_seal_holds(const char *json, size_t size)
{
    static const char key[] = "\"json_sha256\": \"";
    const size_t key_len = sizeof key - 1;
    const char *at = NULL;
    int seals = 0;
    for (const char *p = strstr(json, key); p != NULL; p = strstr(p + 1, key)) {
        size_t i = 0; /* counted as Python's regex counts: the key, 64 lower-case hex digits, a quote */
        while (i < 64 && ((p[key_len + i] >= '0' && p[key_len + i] <= '9') ||
                          (p[key_len + i] >= 'a' && p[key_len + i] <= 'f')))
            i++;
        if (i == 64 && p[key_len + 64] == '"') seals++, at = p;
    }
    if (seals != 1) return -1; /* none, or two: which one was written is unknown */
    char seal[65], digest[65];
    memcpy(seal, at + key_len, 64);
    seal[64] = '\0';
    char *copy = malloc(size);
    if (copy == NULL) return -1;
    memcpy(copy, json, size);
    memset(copy + (at - json) + key_len, '0', 64);
    sha256_hex((const unsigned char *)copy, size, digest);
    free(copy);
    return strcmp(seal, digest) == 0 ? 0 : -1;
}

static unsigned read_u16(const unsigned char *p) { return p[0] | (unsigned)p[1] << 8; }
static unsigned long read_u32(const unsigned char *p)
{
    return p[0] | (unsigned long)p[1] << 8 | (unsigned long)p[2] << 16 | (unsigned long)p[3] << 24;
}

/* The stored member correction.npy of the zip: its (m, 2) little-endian doubles into *out; 0 on success. */
static int npz_correction(Instance *inst, const char *path, const unsigned char *zip, size_t size, double **out,
                          long *rows)
{
    static const char member[] = "correction.npy";
    const size_t name_len = sizeof member - 1;
    for (size_t at = 0; at + 30 <= size; at++) {
        const unsigned char *h = zip + at;
        if (read_u32(h) != 0x04034b50UL || read_u16(h + 26) != name_len || at + 30 + name_len > size ||
            memcmp(h + 30, member, name_len) != 0)
            continue;
        if (read_u16(h + 8) != 0) {
            glue_log(inst, fmi2Error, "%s: correction.npy is compressed (write it with "
                     "flexarm.ilc.write_learned_feedforward, which stores it)", path);
            return -1;
        }
        size_t data = at + 30 + name_len + read_u16(h + 28);
        const unsigned char *npy = zip + data;
        if (data + 12 > size || memcmp(npy, "\x93NUMPY", 6) != 0) break;
        size_t header_len = npy[6] == 1 ? read_u16(npy + 8) : read_u32(npy + 8);
        size_t start = data + (npy[6] == 1 ? 10 : 12) + header_len;
        if (start > size) break;
        char header[256];
        size_t hl = header_len < sizeof header - 1 ? header_len : sizeof header - 1;
        memcpy(header, npy + (npy[6] == 1 ? 10 : 12), hl);
        header[hl] = '\0';
        const char *shape = strstr(header, "'shape': (");
        long m = -1, cols = -1;
        if (strstr(header, "'descr': '<f8'") == NULL || strstr(header, "'fortran_order': False") == NULL ||
            shape == NULL || sscanf(shape, "'shape': (%ld, %ld)", &m, &cols) != 2 || cols != 2 || m < 1 ||
            start + (size_t)m * 2 * sizeof(double) > size) {
            glue_log(inst, fmi2Error, "%s: correction must be little-endian doubles of "
                     "shape (m, 2), C order (header: %s)", path, header);
            return -1;
        }
        *out = malloc((size_t)m * 2 * sizeof(double));
        if (*out == NULL) return -1;
        memcpy(*out, zip + start, (size_t)m * 2 * sizeof(double)); /* every target of these FMUs is little-endian */
        for (long i = 0; i < 2 * m; i++)
            if (!isfinite((*out)[i])) {
                glue_log(inst, fmi2Error, "%s: correction has a non-finite value", path);
                free(*out), *out = NULL;
                return -1;
            }
        *rows = m;
        return 0;
    }
    glue_log(inst, fmi2Error, "%s: no stored member correction.npy (not a learned "
             "feedforward file of flexarm.ilc)", path);
    return -1;
}

fmi2Status learned_ff_load(Instance *inst, const char *trajectory_sha256, const char *parameter_sha256,
                           double **correction, long *rows)
{
    *correction = NULL, *rows = 0;
    char *path = glue_resource_file(inst, LEARNED_FF_RESOURCE);
    if (path == NULL) return fmi2OK; /* no resources folder: nothing learned */
    size_t n = strlen(path), size = 0, json_size = 0;
    char *json_path = malloc(n + 2);
    if (json_path == NULL) {
        free(path);
        return fmi2Error;
    }
    memcpy(json_path, path, n - 4); /* LEARNED_FF_RESOURCE ends in .npz */
    strcpy(json_path + n - 4, ".json");
    char *zip = glue_read_file(path, &size), *json = glue_read_file(json_path, &json_size);
    fmi2Status status = fmi2Error;
    char digest[65], recorded[80];
    if (zip == NULL && json == NULL) {
        status = fmi2OK; /* this FMU carries no learned correction */
        goto done;
    }
    if (zip == NULL || json == NULL) {
        glue_log(inst, fmi2Error, "%s: cannot be read (a learned correction is the .npz with its .json beside it)",
                 zip == NULL ? path : json_path);
        goto done;
    }
    if (memchr(json, '\0', json_size) != NULL || json_seal_holds(json, json_size) != 0) {
        glue_log(inst, fmi2Error, "%s: its seal (json_sha256, the SHA-256 of its own "
                 "bytes) is missing or does not match: edited or corrupt (learn it again)", json_path);
        goto done;
    }
    sha256_hex((const unsigned char *)zip, size, digest);
    if (json_string(json, "format", recorded) || strcmp(recorded, "flexarm-learned-feedforward/1") != 0 ||
        json_string(json, "npz_sha256", recorded) || strcmp(recorded, digest) != 0) {
        glue_log(inst, fmi2Error, "%s differs from the SHA-256 recorded in %s (or that "
                 "is no learned-feedforward file)", path, json_path);
        goto done;
    }
    if (json_string(json, "trajectory_sha256", recorded) || strcmp(recorded, trajectory_sha256) != 0 ||
        json_string(json, "parameter_sha256", recorded) || strcmp(recorded, parameter_sha256) != 0) {
        glue_log(inst, fmi2Error, "%s is stale: it was learnt on other trajectory or "
                 "parameter files than this FMU was built from (learn it again)", path);
        goto done;
    }
    if (npz_correction(inst, path, (const unsigned char *)zip, size, correction, rows) == 0)
        status = fmi2OK;
done:
    free(zip), free(json), free(json_path), free(path);
    return status;
}
