/*
 * Resources of the native FMUs (see fmi2_glue.h): the folder from the file:// URI the host passes,
 * each file read whole and checked against the SHA-256 recorded at build time, and the text format
 * of the constants (labelled lists of IEEE-754 doubles as 16 hex digits: exact on every platform).
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_glue.h"
#include "sha256.h"

static int hex_digit(char ch)
{
    if (ch >= '0' && ch <= '9') return ch - '0';
    if (ch >= 'a' && ch <= 'f') return ch - 'a' + 10;
    if (ch >= 'A' && ch <= 'F') return ch - 'A' + 10;
    return -1;
}

/* Local path of a file:// URI (file:///p, file://localhost/p, file:/p; %XX decoded; Windows drive letters). */
static char *uri_to_path(const char *uri)
{
    const char *p;
    if (uri == NULL) return NULL;
    if (strncmp(uri, "file://localhost/", 17) == 0) p = uri + 16;
    else if (strncmp(uri, "file:///", 8) == 0) p = uri + 7;
    else if (strncmp(uri, "file:/", 6) == 0) p = uri + 5;
    else return NULL;
    char *out = malloc(strlen(p) + 1), *o = out;
    if (out == NULL) return NULL;
    for (; *p; p++) {
        if (*p == '%' && hex_digit(p[1]) >= 0 && hex_digit(p[2]) >= 0) {
            *o++ = (char)(hex_digit(p[1]) * 16 + hex_digit(p[2]));
            p += 2;
        } else *o++ = *p;
    }
    *o = '\0';
#ifdef _WIN32
    if (out[0] == '/' && out[1] && out[2] == ':') memmove(out, out + 1, strlen(out)); /* /C:/dir -> C:/dir */
#endif
    return out;
}

char *glue_resource_dir(const char *uri)
{
    return uri_to_path(uri);
}

char *glue_resource_file(const Instance *inst, const char *name)
{
    const char *dir = inst->resource_dir;
    if (dir == NULL) return NULL;
    size_t n = strlen(dir) + strlen(name) + 2;
    char *path = malloc(n);
    if (path != NULL) snprintf(path, n, "%s%s%s", dir, dir[0] && dir[strlen(dir) - 1] == '/' ? "" : "/", name);
    return path;
}

char *glue_read_file(const char *path, size_t *size)
{
    FILE *f = fopen(path, "rb");
    if (f == NULL) return NULL;
    size_t cap = 1 << 16, n = 0;
    char *buf = malloc(cap + 1);
    for (size_t got; buf != NULL && (got = fread(buf + n, 1, cap - n, f)) > 0;) {
        n += got;
        if (n == cap) {
            char *bigger = realloc(buf, 2 * cap + 1);
            if (bigger == NULL) free(buf);
            buf = bigger;
            cap *= 2;
        }
    }
    fclose(f);
    if (buf != NULL) buf[n] = '\0';
    *size = n;
    return buf;
}

int glue_read_doubles(const Instance *inst, const char *file, const char *text, const char *name, double *out,
                      size_t n)
{
    size_t len = strlen(name);
    const char *p = text;
    for (;;) { /* the label at the start of a line */
        p = strstr(p, name);
        if (p == NULL) {
            glue_log(inst, fmi2Error, "resources/%s: no entry '%s' (the file does not belong to this FMU)", file, name);
            return -1;
        }
        if ((p == text || p[-1] == '\n') && (p[len] == ' ' || p[len] == '\n')) break;
        p += len;
    }
    p += len;
    char *end;
    unsigned long count = strtoul(p, &end, 10);
    if (end == p || count != n) {
        glue_log(inst, fmi2Error, "resources/%s: '%s' has %lu values, expected %zu", file, name, count, n);
        return -1;
    }
    p = end;
    for (size_t k = 0; k < n; k++) {
        while (*p == ' ' || *p == '\n' || *p == '\r' || *p == '\t') p++;
        uint64_t bits = 0;
        for (int d = 0; d < 16; d++, p++) {
            int v = hex_digit(*p);
            if (v < 0) {
                glue_log(inst, fmi2Error, "resources/%s: '%s' value %zu is not 16 hex digits", file, name, k);
                return -1;
            }
            bits = bits << 4 | (uint64_t)v;
        }
        memcpy(&out[k], &bits, sizeof bits);
    }
    return 0;
}

char *glue_read_resource(const Instance *inst, const char *file, const char *when, size_t *size)
{
    const ResourceInfo *res = NULL;
    for (size_t r = 0; r < MODEL_INFO.n_resources; r++)
        if (strcmp(MODEL_INFO.resources[r].file, file) == 0) res = &MODEL_INFO.resources[r];
    if (res == NULL) {
        glue_log(inst, fmi2Error, "%s: %s is not a resource of this build", when, file);
        return NULL;
    }
    char *path = glue_resource_file(inst, file);
    if (path == NULL) {
        glue_log(inst, fmi2Error, "%s: no resources folder to read %s from (fmuResourceLocation is no file:// URI)",
                 when, file);
        return NULL;
    }
    char *text = glue_read_file(path, size);
    if (text == NULL) {
        glue_log(inst, fmi2Error, "%s: cannot read the resource %s (it ships inside the FMU in resources/; unpack the "
                 "whole FMU and keep it until the instance is freed)", when, path);
    } else {
        char digest[65];
        sha256_hex((const unsigned char *)text, *size, digest);
        if (strcmp(digest, res->sha256) != 0) {
            glue_log(inst, fmi2Error, "%s: resource %s has SHA-256 %s, but this FMU was built with %s (the file was "
                     "changed or belongs to another build: rebuild the FMU)", when, path, digest, res->sha256);
            free(text);
            text = NULL;
        }
    }
    free(path);
    return text;
}

static int on_demand(const char *file)
{
    for (const char *const *p = MODEL_INFO.on_demand; p != NULL && *p != NULL; p++)
        if (strcmp(*p, file) == 0) return 1;
    return 0;
}

int glue_load_resources(Instance *inst, const char *uri)
{
    if (MODEL_INFO.n_resources == 0) return 0;
    if (inst->resource_dir == NULL) {
        glue_log(inst, fmi2Error, "fmi2Instantiate: fmuResourceLocation '%s' is not a file:// URI of the FMU's "
                 "resources folder (unpack the whole FMU and pass its resources/ folder)", uri ? uri : "(null)");
        return -1;
    }
    char *contents[8] = {0};
    size_t sizes[8] = {0};
    int rc = 0;
    for (size_t r = 0; r < MODEL_INFO.n_resources && r < 8 && rc == 0; r++)
        if (!on_demand(MODEL_INFO.resources[r].file)) {
            contents[r] = glue_read_resource(inst, MODEL_INFO.resources[r].file, "fmi2Instantiate", &sizes[r]);
            if (contents[r] == NULL) rc = -1;
        }
    if (rc == 0) rc = MODEL_INFO.load(inst, contents, sizes);
    for (size_t r = 0; r < 8; r++) free(contents[r]);
    return rc;
}

#define START_VALUES_FILE "flexarm_start_values.txt"

/* One line "name value" of the start-values file; value: the IEEE-754 bits as 16 hex digits. */
static int apply_start_value(Instance *inst, const char *name, size_t len, const char *hex, const char *line_end)
{
    uint64_t bits = 0;
    int d = 0;
    for (; d < 16 && hex + d < line_end && hex_digit(hex[d]) >= 0; d++) bits = bits << 4 | (uint64_t)hex_digit(hex[d]);
    if (d != 16 || hex + 16 != line_end) {
        glue_log(inst, fmi2Error, "fmi2Instantiate: resources/%s: line '%.*s' is not 'name' and 16 hex digits",
                 START_VALUES_FILE, (int)(line_end - name), name);
        return -1;
    }
    double x;
    memcpy(&x, &bits, sizeof x);
    for (size_t i = 0; i < MODEL_INFO.n_vars; i++) {
        const VarInfo *v = &MODEL_INFO.vars[i];
        if (strlen(v->name) != len || strncmp(v->name, name, len) != 0) continue;
        if (v->causality != CA_PARAMETER) break;
        if (!isfinite(x) || x < v->min || x > v->max || (v->type != VT_REAL && x != floor(x))) {
            glue_log(inst, fmi2Error, "fmi2Instantiate: resources/%s: %s = %.17g is outside its range [%.17g, %.17g]"
                     "%s", START_VALUES_FILE, v->name, x, v->min, v->max, v->type != VT_REAL ? " of whole numbers" : "");
            return -1;
        }
        inst->starts[i] = x;
        return 0;
    }
    glue_log(inst, fmi2Error, "fmi2Instantiate: resources/%s: '%.*s' is not a parameter of %s", START_VALUES_FILE,
             (int)len, name, MODEL_INFO.model_identifier);
    return -1;
}

int glue_load_start_values(Instance *inst, const char *uri)
{
    char *dir = uri != NULL ? uri_to_path(uri) : NULL;
    if (dir == NULL) return 0; /* no resources folder: the table's start values */
    size_t n = strlen(dir) + strlen(START_VALUES_FILE) + 2, size = 0;
    char *path = malloc(n);
    if (path == NULL) {
        free(dir);
        return -1;
    }
    snprintf(path, n, "%s%s%s", dir, dir[0] && dir[strlen(dir) - 1] == '/' ? "" : "/", START_VALUES_FILE);
    char *text = glue_read_file(path, &size);
    free(path);
    free(dir);
    if (text == NULL) return 0; /* no file: the table's start values */
    int rc = 0;
    for (const char *p = text; *p && rc == 0;) {
        const char *end = p;
        while (*end && *end != '\n' && *end != '\r') end++;
        if (end > p) {
            const char *name = p, *sep = p;
            while (sep < end && *sep != ' ') sep++;
            const char *hex = sep;
            while (hex < end && *hex == ' ') hex++;
            rc = apply_start_value(inst, name, (size_t)(sep - name), hex, end);
        }
        p = *end ? end + 1 : end;
    }
    free(text);
    return rc;
}
