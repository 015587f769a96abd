/*
 * fmi2_host: a minimal native FMI 2.0 co-simulation host (no Python in it).
 *
 * Runs one unzipped FMU: reads modelDescription.xml (GUID, model identifier,
 * variables), loads binaries/linux64/<modelIdentifier>.so, instantiates,
 * sets parameters in initialisation mode, steps N times with inputs from a
 * CSV file, and prints the outputs as CSV (full precision) on stdout. The
 * FMU's log goes to stderr, formatted as FMI 2.0 prescribes (printf-style).
 *
 *   gcc -std=c11 -O2 -I<fmpy>/c-code -o fmi2_host fmi2_host.c -ldl
 *   fmi2_host FMU_DIR [--steps N] [--dt H] [--set NAME=VALUE]... [--inputs FILE.csv]
 *                     [--out NAME,NAME,...] [--check-errors] [--quiet] [--logging-off]
 *
 *   --steps N        communication steps (default 1000); N + 1 rows are printed
 *   --dt H           communication step in s (default 0.001)
 *   --set NAME=VALUE a parameter or input set in initialisation mode (type from modelDescription.xml)
 *   --inputs FILE    CSV: a header of Real input names, then one row per communication point k
 *                    (row k is set at t_k before the outputs are read; the last row is held)
 *   --out NAMES      Real variables to print (default: every Real output)
 *   --check-errors   first, on a separate instance, check that misuse returns fmi2Error:
 *                    fmi2DoStep and fmi2GetReal before initialisation, NaN into the first Real
 *                    input, a fixed parameter set after initialisation
 *   --quiet          do not print log messages with status fmi2OK
 *   --logging-off    instantiate with loggingOn = fmi2False (the FMU must still report errors)
 *
 * Exit status: 0 success, 1 usage, 2 the FMU could not be loaded or instantiated,
 * 3 an FMI call returned fmi2Error or worse (or --check-errors found a problem).
 */
#define _GNU_SOURCE
#ifdef _WIN32 /* the win64 build (tests/test_native_platforms.py runs it under wine) */
#include <windows.h>
#define dlopen(path, flags) ((void *)LoadLibraryA(path))
#define dlsym(h, name) ((void *)GetProcAddress((HMODULE)(h), name))
#define dlerror() "LoadLibrary failed"
#define realpath(path, resolved) _fullpath(NULL, path, 0)
#define PLATFORM_BINARY "binaries/win64/%s.dll"
#else
#include <dlfcn.h>
#define PLATFORM_BINARY "binaries/linux64/%s.so"
#endif
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

typedef struct {
    char name[128];
    unsigned vr;
    char type[16];      /* Real, Integer, Enumeration, Boolean, String */
    char causality[32];
    char variability[32];
} Variable;

static Variable *vars;
static size_t n_vars;
static int quiet;

static const char *STATUS[] = {"OK", "Warning", "Discard", "Error", "Fatal", "Pending"};

static void die(int code, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "fmi2_host: ");
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, "\n");
    va_end(ap);
    exit(code);
}

/* FMI 2.0 logger: `message` is a printf format with the remaining arguments. */
static void logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status, fmi2String category,
                   fmi2String message, ...)
{
    (void)env;
    if (quiet && status == fmi2OK) return;
    va_list ap;
    va_start(ap, message);
    fprintf(stderr, "[%s] %s (%s): ", status <= fmi2Pending ? STATUS[status] : "?", instance ? instance : "",
            category ? category : "");
    vfprintf(stderr, message, ap);
    fprintf(stderr, "\n");
    va_end(ap);
}

/* -- modelDescription.xml (the attributes this host needs) --------------------------------- */
static char *read_file(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *buf = malloc((size_t)n + 1);
    if (buf && fread(buf, 1, (size_t)n, f) != (size_t)n) {
        free(buf);
        buf = NULL;
    }
    if (buf) buf[n] = '\0';
    fclose(f);
    return buf;
}

/* Value of attribute `name` in the tag [start, end), copied into out; 0 if absent. */
static int attribute(const char *start, const char *end, const char *name, char *out, size_t size)
{
    char key[64];
    snprintf(key, sizeof key, " %s=\"", name);
    for (const char *p = start; p && p < end; p++) {
        p = strstr(p, key);
        if (!p || p >= end) return 0;
        const char *v = p + strlen(key), *q = strchr(v, '"');
        if (!q || q > end) return 0;
        size_t n = (size_t)(q - v) < size - 1 ? (size_t)(q - v) : size - 1;
        memcpy(out, v, n);
        out[n] = '\0';
        return 1;
    }
    return 0;
}

static void parse_model_description(const char *xml, char *guid, char *model_id)
{
    const char *root = strstr(xml, "<fmiModelDescription");
    const char *cs = strstr(xml, "<CoSimulation");
    if (!root || !cs || !attribute(root, strchr(root, '>'), "guid", guid, 128) ||
        !attribute(cs, strchr(cs, '>'), "modelIdentifier", model_id, 128))
        die(2, "modelDescription.xml: no guid or no <CoSimulation modelIdentifier>");
    size_t cap = 64;
    vars = malloc(cap * sizeof *vars);
    for (const char *p = strstr(xml, "<ScalarVariable"); p; p = strstr(p + 1, "<ScalarVariable")) {
        const char *end = strchr(p, '>');
        Variable v = {0};
        char vr[32] = "";
        if (!end || !attribute(p, end, "name", v.name, sizeof v.name) ||
            !attribute(p, end, "valueReference", vr, sizeof vr))
            die(2, "modelDescription.xml: a ScalarVariable without name or valueReference");
        if (!attribute(p, end, "causality", v.causality, sizeof v.causality)) strcpy(v.causality, "local");
        if (!attribute(p, end, "variability", v.variability, sizeof v.variability))
            strcpy(v.variability, "continuous");
        v.vr = (unsigned)strtoul(vr, NULL, 10);
        const char *t = strchr(end, '<'); /* the type element follows the start tag */
        if (!t || sscanf(t + 1, "%15[A-Za-z]", v.type) != 1) die(2, "modelDescription.xml: %s has no type", v.name);
        if (n_vars == cap) vars = realloc(vars, (cap *= 2) * sizeof *vars);
        vars[n_vars++] = v;
    }
}

static const Variable *find(const char *name)
{
    for (size_t i = 0; i < n_vars; i++)
        if (strcmp(vars[i].name, name) == 0) return &vars[i];
    die(1, "no variable named '%s' in modelDescription.xml", name);
    return NULL;
}

/* -- the FMU's functions --------------------------------------------------------------------- */
typedef struct {
    fmi2InstantiateTYPE *instantiate;
    fmi2FreeInstanceTYPE *freeInstance;
    fmi2SetupExperimentTYPE *setupExperiment;
    fmi2EnterInitializationModeTYPE *enterInitializationMode;
    fmi2ExitInitializationModeTYPE *exitInitializationMode;
    fmi2TerminateTYPE *terminate;
    fmi2GetRealTYPE *getReal;
    fmi2SetRealTYPE *setReal;
    fmi2SetIntegerTYPE *setInteger;
    fmi2SetBooleanTYPE *setBoolean;
    fmi2SetStringTYPE *setString;
    fmi2DoStepTYPE *doStep;
} Api;

static void load(Api *api, const char *library)
{
    void *h = dlopen(library, RTLD_NOW | RTLD_LOCAL);
    if (!h) die(2, "cannot load %s: %s", library, dlerror());
#define SYM(field, name)                                                                                   \
    if (!(*(void **)&api->field = dlsym(h, name))) die(2, "%s does not export %s", library, name);
    SYM(instantiate, "fmi2Instantiate")
    SYM(freeInstance, "fmi2FreeInstance")
    SYM(setupExperiment, "fmi2SetupExperiment")
    SYM(enterInitializationMode, "fmi2EnterInitializationMode")
    SYM(exitInitializationMode, "fmi2ExitInitializationMode")
    SYM(terminate, "fmi2Terminate")
    SYM(getReal, "fmi2GetReal")
    SYM(setReal, "fmi2SetReal")
    SYM(setInteger, "fmi2SetInteger")
    SYM(setBoolean, "fmi2SetBoolean")
    SYM(setString, "fmi2SetString")
    SYM(doStep, "fmi2DoStep")
#undef SYM
}

static void check(fmi2Status status, const char *what)
{
    if (status > fmi2Warning) die(3, "%s returned fmi2%s", what, STATUS[status]);
}

static fmi2Status set_value(const Api *api, fmi2Component c, const Variable *v, const char *text)
{
    const fmi2ValueReference vr = v->vr;
    if (strcmp(v->type, "Real") == 0) {
        fmi2Real x = strtod(text, NULL);
        return api->setReal(c, &vr, 1, &x);
    }
    if (strcmp(v->type, "Integer") == 0 || strcmp(v->type, "Enumeration") == 0) {
        fmi2Integer x = (fmi2Integer)strtol(text, NULL, 10);
        return api->setInteger(c, &vr, 1, &x);
    }
    if (strcmp(v->type, "Boolean") == 0) {
        fmi2Boolean x = strcmp(text, "true") == 0 || strcmp(text, "1") == 0;
        return api->setBoolean(c, &vr, 1, &x);
    }
    fmi2String x = text;
    return api->setString(c, &vr, 1, &x);
}

/* file:// URI of a folder (percent-encoding everything but unreserved characters and '/'). */
static char *file_uri(const char *folder)
{
    char *real = realpath(folder, NULL);
    if (!real) die(2, "no such folder: %s", folder);
    char *uri = malloc(strlen(real) * 3 + 16), *o = uri;
    o += sprintf(o, real[0] == '/' ? "file://" : "file:///"); /* Windows: file:///C:/dir */
    for (const char *p = real; *p; p++) {
        unsigned char ch = (unsigned char)*p;
        if (ch == '\\') ch = '/';
        if ((ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') || strchr("/-._~", ch))
            *o++ = (char)ch;
        else
            o += sprintf(o, "%%%02X", ch);
    }
    *o = '\0';
    free(real);
    return uri;
}

/* Misuse must give fmi2Error (and a log message), never a crash; the instance stays usable. */
static int check_errors(const Api *api, const fmi2CallbackFunctions *cb, const char *guid, const char *uri)
{
    int problems = 0;
    fmi2Component c = api->instantiate("check-errors", fmi2CoSimulation, guid, uri, cb, fmi2False, fmi2True);
    if (!c) die(2, "fmi2Instantiate failed (see the log above)");
    const Variable *input = NULL, *param = NULL, *output = NULL;
    for (size_t i = 0; i < n_vars; i++) {
        if (!input && strcmp(vars[i].causality, "input") == 0 && strcmp(vars[i].type, "Real") == 0) input = &vars[i];
        if (!param && strcmp(vars[i].causality, "parameter") == 0 && strcmp(vars[i].variability, "fixed") == 0 &&
            strcmp(vars[i].type, "Real") == 0)
            param = &vars[i];
        if (!output && strcmp(vars[i].causality, "output") == 0 && strcmp(vars[i].type, "Real") == 0) output = &vars[i];
    }
    fmi2Real y;
#define EXPECT(call, want, what)                                                                           \
    do {                                                                                                   \
        fmi2Status s_ = (call);                                                                            \
        int ok_ = s_ == (want);                                                                            \
        printf("check-errors: %-50s -> fmi2%s %s\n", what, STATUS[s_], ok_ ? "(as expected)" : "(WRONG)");  \
        problems += !ok_;                                                                                  \
    } while (0)
    EXPECT(api->doStep(c, 0.0, 1e-3, fmi2True), fmi2Error, "fmi2DoStep before initialisation");
    if (output) {
        fmi2ValueReference vr = output->vr;
        EXPECT(api->getReal(c, &vr, 1, &y), fmi2Error, "fmi2GetReal before initialisation");
    }
    EXPECT(api->setupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0), fmi2OK, "fmi2SetupExperiment");
    EXPECT(api->enterInitializationMode(c), fmi2OK, "fmi2EnterInitializationMode");
    EXPECT(api->exitInitializationMode(c), fmi2OK, "fmi2ExitInitializationMode");
    if (input) {
        fmi2ValueReference vr = input->vr;
        fmi2Real nan = NAN, zero = 0.0;
        EXPECT(api->setReal(c, &vr, 1, &nan), fmi2Error, "NaN into the first Real input");
        EXPECT(api->doStep(c, 0.0, 1e-3, fmi2True), fmi2Error, "fmi2DoStep while that input is rejected");
        EXPECT(api->setReal(c, &vr, 1, &zero), fmi2OK, "a valid value for it");
    }
    if (param) EXPECT(set_value(api, c, param, "0"), fmi2Error, "a fixed parameter after initialisation");
    EXPECT(api->doStep(c, 0.0, 1e-3, fmi2True), fmi2OK, "fmi2DoStep after the errors");
    EXPECT(api->terminate(c), fmi2OK, "fmi2Terminate");
#undef EXPECT
    api->freeInstance(c);
    return problems;
}

int main(int argc, char **argv)
{
    if (argc < 2 || argv[1][0] == '-') die(1, "usage: fmi2_host FMU_DIR [--steps N] [--dt H] [--set NAME=VALUE]... "
                                           "[--inputs FILE.csv] [--out NAME,...] [--check-errors] [--quiet] [--logging-off]");
    const char *dir = argv[1], *inputs_file = NULL, *out_names = NULL;
    long steps = 1000;
    double dt = 1e-3;
    int do_check = 0, n_sets = 0;
    fmi2Boolean logging_on = fmi2True;
    const char **sets = calloc((size_t)argc, sizeof *sets);
    for (int i = 2; i < argc; i++) {
        const char *a = argv[i], *next = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--steps") == 0 && next) steps = strtol(argv[++i], NULL, 10);
        else if (strcmp(a, "--dt") == 0 && next) dt = strtod(argv[++i], NULL);
        else if (strcmp(a, "--set") == 0 && next) sets[n_sets++] = argv[++i];
        else if (strcmp(a, "--inputs") == 0 && next) inputs_file = argv[++i];
        else if (strcmp(a, "--out") == 0 && next) out_names = argv[++i];
        else if (strcmp(a, "--check-errors") == 0) do_check = 1;
        else if (strcmp(a, "--quiet") == 0) quiet = 1;
        else if (strcmp(a, "--logging-off") == 0) logging_on = fmi2False;
        else die(1, "unknown or incomplete option '%s'", a);
    }
    char path[PATH_MAX], guid[128], model_id[128];
    snprintf(path, sizeof path, "%s/modelDescription.xml", dir);
    char *xml = read_file(path);
    if (!xml) die(2, "cannot read %s", path);
    parse_model_description(xml, guid, model_id);
    snprintf(path, sizeof path, "%s/" PLATFORM_BINARY, dir, model_id);
    Api api;
    load(&api, path);
    snprintf(path, sizeof path, "%s/resources", dir);
    char *uri = file_uri(path);
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};

    if (do_check && check_errors(&api, &cb, guid, uri) != 0) die(3, "--check-errors: misuse was not reported");

    /* what to print */
    size_t n_out = 0;
    const Variable **outs = calloc(n_vars, sizeof *outs);
    if (out_names) {
        char *copy = strdup(out_names);
        for (char *tok = strtok(copy, ","); tok; tok = strtok(NULL, ",")) outs[n_out++] = find(tok);
    } else {
        for (size_t i = 0; i < n_vars; i++)
            if (strcmp(vars[i].causality, "output") == 0 && strcmp(vars[i].type, "Real") == 0) outs[n_out++] = &vars[i];
    }
    fmi2ValueReference *out_vr = calloc(n_out + 1, sizeof *out_vr);
    fmi2Real *y = calloc(n_out + 1, sizeof *y);
    for (size_t i = 0; i < n_out; i++) out_vr[i] = outs[i]->vr;

    /* inputs: CSV header of names, one row per communication point */
    size_t n_in = 0, n_rows = 0;
    fmi2ValueReference *in_vr = NULL;
    double *rows = NULL;
    if (inputs_file) {
        FILE *f = fopen(inputs_file, "r");
        if (!f) die(1, "cannot read %s", inputs_file);
        static char line[1 << 16];
        if (!fgets(line, sizeof line, f)) die(1, "%s: empty", inputs_file);
        line[strcspn(line, "\r\n")] = '\0';
        in_vr = calloc(n_vars, sizeof *in_vr);
        for (char *tok = strtok(line, ","); tok; tok = strtok(NULL, ",")) in_vr[n_in++] = find(tok)->vr;
        size_t cap = 1024;
        rows = malloc(cap * n_in * sizeof *rows);
        while (fgets(line, sizeof line, f)) {
            if (n_rows == cap) rows = realloc(rows, (cap *= 2) * n_in * sizeof *rows);
            char *p = line;
            for (size_t j = 0; j < n_in; j++) {
                rows[n_rows * n_in + j] = strtod(p, &p);
                if (*p == ',') p++;
            }
            n_rows++;
        }
        fclose(f);
    }

    fmi2Component c = api.instantiate("host", fmi2CoSimulation, guid, uri, &cb, fmi2False, logging_on);
    if (!c) die(2, "fmi2Instantiate failed (see the log above)");
    check(api.setupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0), "fmi2SetupExperiment");
    check(api.enterInitializationMode(c), "fmi2EnterInitializationMode");
    for (int i = 0; i < n_sets; i++) {
        char name[128];
        const char *eq = strchr(sets[i], '=');
        if (!eq || (size_t)(eq - sets[i]) >= sizeof name) die(1, "--set %s: expected NAME=VALUE", sets[i]);
        memcpy(name, sets[i], (size_t)(eq - sets[i]));
        name[eq - sets[i]] = '\0';
        check(set_value(&api, c, find(name), eq + 1), sets[i]);
    }
    check(api.exitInitializationMode(c), "fmi2ExitInitializationMode");

    printf("time");
    for (size_t i = 0; i < n_out; i++) printf(",%s", outs[i]->name);
    printf("\n");
    for (long k = 0; k <= steps; k++) {
        double t = (double)k * dt;
        if (n_rows > 0 && k < steps) {
            size_t r = (size_t)k < n_rows ? (size_t)k : n_rows - 1;
            check(api.setReal(c, in_vr, n_in, rows + r * n_in), "fmi2SetReal");
        }
        check(api.getReal(c, out_vr, n_out, y), "fmi2GetReal");
        printf("%.17g", t);
        for (size_t i = 0; i < n_out; i++) printf(",%.17g", y[i]);
        printf("\n");
        if (k < steps) check(api.doStep(c, t, dt, fmi2True), "fmi2DoStep");
    }
    check(api.terminate(c), "fmi2Terminate");
    api.freeInstance(c);
    fflush(stdout);
    return 0;
}
