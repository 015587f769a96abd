/*
 * The native plant's step cost without Python: a C host that loads the FMU's shipped binary (dlopen) and times
 * fmi2SetReal (torques) + fmi2DoStep (1 ms) + fmi2GetReal (every output), as benchmarks/bench_native.py does
 * through ctypes. Compiled and run by bench_native.py:
 *
 *   plant_step_timing LIBRARY RESOURCE_URI GUID TORQUES_FILE REPEATS TAU_VRS OUTPUT_VRS
 *
 * TORQUES_FILE: one "tau1 tau2" pair per line (one per step); TAU_VRS, OUTPUT_VRS: comma-separated value
 * references. Prints the best wall time per step over REPEATS runs, in microseconds.
 */
#define _POSIX_C_SOURCE 199309L
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "fmi2Functions.h"

#define MAX_STEPS 100000
#define MAX_OUTPUTS 256

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...)
{
    (void)env;
    fprintf(stderr, "[%s, status %d, %s] %s\n", name, (int)status, category, message);
}

static double seconds(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static size_t parse_vrs(const char *text, fmi2ValueReference *out, size_t max)
{
    size_t n = 0;
    for (const char *p = text; *p && n < max; p++) {
        out[n++] = (fmi2ValueReference)strtoul(p, (char **)&p, 10);
        if (*p != ',') break;
    }
    return n;
}

static void *symbol(void *lib, const char *name)
{
    void *f = dlsym(lib, name);
    if (f == NULL) {
        fprintf(stderr, "the library does not export %s\n", name);
        exit(2);
    }
    return f;
}

int main(int argc, char **argv)
{
    if (argc != 8) {
        fprintf(stderr, "usage: %s LIBRARY RESOURCE_URI GUID TORQUES_FILE REPEATS TAU_VRS OUTPUT_VRS\n", argv[0]);
        return 1;
    }
    void *lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (lib == NULL) {
        fprintf(stderr, "cannot load %s: %s\n", argv[1], dlerror());
        return 2;
    }
    fmi2InstantiateTYPE *instantiate = (fmi2InstantiateTYPE *)symbol(lib, "fmi2Instantiate");
    fmi2ResetTYPE *reset = (fmi2ResetTYPE *)symbol(lib, "fmi2Reset");
    fmi2SetupExperimentTYPE *setup = (fmi2SetupExperimentTYPE *)symbol(lib, "fmi2SetupExperiment");
    fmi2EnterInitializationModeTYPE *enter = (fmi2EnterInitializationModeTYPE *)symbol(lib, "fmi2EnterInitializationMode");
    fmi2ExitInitializationModeTYPE *leave = (fmi2ExitInitializationModeTYPE *)symbol(lib, "fmi2ExitInitializationMode");
    fmi2SetRealTYPE *set_real = (fmi2SetRealTYPE *)symbol(lib, "fmi2SetReal");
    fmi2GetRealTYPE *get_real = (fmi2GetRealTYPE *)symbol(lib, "fmi2GetReal");
    fmi2DoStepTYPE *do_step = (fmi2DoStepTYPE *)symbol(lib, "fmi2DoStep");
    fmi2FreeInstanceTYPE *free_instance = (fmi2FreeInstanceTYPE *)symbol(lib, "fmi2FreeInstance");

    static double tau[MAX_STEPS][2];
    size_t n_steps = 0;
    FILE *f = fopen(argv[4], "r");
    if (f == NULL) {
        fprintf(stderr, "cannot read %s\n", argv[4]);
        return 1;
    }
    while (n_steps < MAX_STEPS && fscanf(f, "%lf %lf", &tau[n_steps][0], &tau[n_steps][1]) == 2) n_steps++;
    fclose(f);
    const int repeats = atoi(argv[5]);
    fmi2ValueReference vr_tau[2], vr_out[MAX_OUTPUTS];
    const size_t n_tau = parse_vrs(argv[6], vr_tau, 2), n_out = parse_vrs(argv[7], vr_out, MAX_OUTPUTS);
    if (n_steps == 0 || repeats < 1 || n_tau != 2 || n_out == 0) {
        fprintf(stderr, "nothing to time (%zu steps, %d repeats, %zu torques, %zu outputs)\n", n_steps, repeats,
                n_tau, n_out);
        return 1;
    }
    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    fmi2Component c = instantiate("timing", fmi2CoSimulation, argv[3], argv[2], &callbacks, fmi2False, fmi2False);
    if (c == NULL) return 3;
    double y[MAX_OUTPUTS], best = 1e30;
    for (int r = 0; r < repeats; r++) {
        if (reset(c) > fmi2Warning || setup(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) > fmi2Warning ||
            enter(c) > fmi2Warning || set_real(c, vr_tau, 2, tau[0]) > fmi2Warning || leave(c) > fmi2Warning)
            return 4;
        const double t0 = seconds();
        for (size_t k = 0; k < n_steps; k++) {
            set_real(c, vr_tau, 2, tau[k]);
            if (do_step(c, (double)k * 1e-3, 1e-3, fmi2True) != fmi2OK) return 5;
            get_real(c, vr_out, n_out, y);
        }
        const double per_step = (seconds() - t0) / (double)n_steps;
        if (per_step < best) best = per_step;
    }
    free_instance(c);
    printf("%.3f\n", best * 1e6);
    return 0;
}
