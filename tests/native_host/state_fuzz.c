/*
 * state_fuzz: FMU states attacked as a misbehaving host would (tests/test_native_state_fuzz.py builds this and the
 * native FMUs' sources with AddressSanitizer and UBSan and runs it; tests/test_python_state_fuzz.py the same with
 * the Python FMUs' C front end).
 *
 *   state_fuzz LIB.so,UNZIPPED_DIR,GUID[,IN_MEMORY_BYTES] [...]
 *
 * IN_MEMORY_BYTES: how many bytes of the in-memory state to flip (default: the serialised length less its 16-byte
 * tag and checksum, the native FMUs' flat snapshot).
 *
 * Each FMU is loaded (RTLD_LOCAL: every FMU has its own tables, as in a real host), instantiated, initialised
 * and stepped 5 times; then, for each FMU:
 *   - every bit of its serialised state flipped in turn and given to fmi2DeSerializeFMUstate;
 *   - every bit of its in-memory state flipped in turn (as a host scribbling on it would) and the state given to
 *     fmi2SetFMUstate (then flipped back);
 *   - its state given to every other FMU: fmi2SetFMUstate, fmi2SerializedFMUstateSize, fmi2SerializeFMUstate,
 *     fmi2FreeFMUstate, and its serialised bytes to fmi2DeSerializeFMUstate; its instance to the other FMU's
 *     fmi2FreeInstance and fmi2DoStep;
 *   - a state freed, then set and freed again;
 *   - the original state and its serialised bytes still restore the FMU exactly (the checks refuse nothing sound);
 *   - fmi2FreeInstance twice, then fmi2DoStep on the freed instance.
 * Each line of output: "<model identifier> <check> <tried> <accepted>". Every attack must be refused
 * (accepted 0); a sanitizer report aborts the run. Exit status: 0 all refused, 1 something accepted, 2 usage
 * or set-up failure.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <limits.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#define MAX_FMUS 16
#define STEPS 5

typedef struct {
    const char *id; /* model identifier, for the report */
    fmi2Component c;
    fmi2FMUstate state;
    fmi2Byte *bytes;
    size_t n_bytes;
    long in_memory_bytes; /* < 0: n_bytes - 16 */
    fmi2InstantiateTYPE *instantiate;
    fmi2FreeInstanceTYPE *free_instance;
    fmi2SetupExperimentTYPE *setup;
    fmi2EnterInitializationModeTYPE *enter_init;
    fmi2ExitInitializationModeTYPE *exit_init;
    fmi2DoStepTYPE *do_step;
    fmi2GetRealTYPE *get_real;
    fmi2GetFMUstateTYPE *get_state;
    fmi2SetFMUstateTYPE *set_state;
    fmi2FreeFMUstateTYPE *free_state;
    fmi2SerializedFMUstateSizeTYPE *serialized_size;
    fmi2SerializeFMUstateTYPE *serialize;
    fmi2DeSerializeFMUstateTYPE *deserialize;
} Fmu;

static long n_messages;

static void count_log(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status, fmi2String category,
                      fmi2String message, ...)
{
    (void)env, (void)instance, (void)status, (void)category, (void)message;
    n_messages++;
}

static int failures;

static void report(const Fmu *f, const char *check, long tried, long accepted)
{
    printf("%s %s %ld %ld\n", f->id, check, tried, accepted);
    if (accepted != 0) failures = 1;
}

static void *sym(void *lib, const char *name)
{
    void *p = dlsym(lib, name);
    if (p == NULL) {
        fprintf(stderr, "state_fuzz: %s missing: %s\n", name, dlerror());
        exit(2);
    }
    return p;
}

static const fmi2CallbackFunctions CALLBACKS = {count_log, calloc, free, NULL, NULL};

static void load(Fmu *f, char *spec)
{
    char *lib_path = strtok(spec, ","), *dir = strtok(NULL, ","), *guid = strtok(NULL, ","),
         *in_memory = strtok(NULL, ",");
    if (lib_path == NULL || dir == NULL || guid == NULL) {
        fprintf(stderr, "state_fuzz: expected LIB,DIR,GUID[,IN_MEMORY_BYTES]\n");
        exit(2);
    }
    f->in_memory_bytes = in_memory != NULL ? strtol(in_memory, NULL, 10) : -1;
    void *lib = dlopen(lib_path, RTLD_NOW | RTLD_LOCAL);
    if (lib == NULL) {
        fprintf(stderr, "state_fuzz: %s\n", dlerror());
        exit(2);
    }
    f->id = strrchr(lib_path, '/') ? strrchr(lib_path, '/') + 1 : lib_path;
    f->instantiate = (fmi2InstantiateTYPE *)sym(lib, "fmi2Instantiate");
    f->free_instance = (fmi2FreeInstanceTYPE *)sym(lib, "fmi2FreeInstance");
    f->setup = (fmi2SetupExperimentTYPE *)sym(lib, "fmi2SetupExperiment");
    f->enter_init = (fmi2EnterInitializationModeTYPE *)sym(lib, "fmi2EnterInitializationMode");
    f->exit_init = (fmi2ExitInitializationModeTYPE *)sym(lib, "fmi2ExitInitializationMode");
    f->do_step = (fmi2DoStepTYPE *)sym(lib, "fmi2DoStep");
    f->get_real = (fmi2GetRealTYPE *)sym(lib, "fmi2GetReal");
    f->get_state = (fmi2GetFMUstateTYPE *)sym(lib, "fmi2GetFMUstate");
    f->set_state = (fmi2SetFMUstateTYPE *)sym(lib, "fmi2SetFMUstate");
    f->free_state = (fmi2FreeFMUstateTYPE *)sym(lib, "fmi2FreeFMUstate");
    f->serialized_size = (fmi2SerializedFMUstateSizeTYPE *)sym(lib, "fmi2SerializedFMUstateSize");
    f->serialize = (fmi2SerializeFMUstateTYPE *)sym(lib, "fmi2SerializeFMUstate");
    f->deserialize = (fmi2DeSerializeFMUstateTYPE *)sym(lib, "fmi2DeSerializeFMUstate");
    char uri[PATH_MAX + 32];
    snprintf(uri, sizeof uri, "file://%s/resources", dir);
    f->c = f->instantiate("fuzz", fmi2CoSimulation, guid, uri, &CALLBACKS, fmi2False, fmi2False);
    if (f->c == NULL || f->setup(f->c, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK ||
        f->enter_init(f->c) != fmi2OK || f->exit_init(f->c) != fmi2OK) {
        fprintf(stderr, "state_fuzz: %s could not be instantiated and initialised\n", f->id);
        exit(2);
    }
    for (int k = 0; k < STEPS; k++)
        if (f->do_step(f->c, k * 1e-3, 1e-3, fmi2True) != fmi2OK) {
            fprintf(stderr, "state_fuzz: %s: fmi2DoStep failed\n", f->id);
            exit(2);
        }
    if (f->get_state(f->c, &f->state) != fmi2OK || f->serialized_size(f->c, f->state, &f->n_bytes) != fmi2OK ||
        (f->bytes = malloc(f->n_bytes)) == NULL || f->serialize(f->c, f->state, f->bytes, f->n_bytes) != fmi2OK) {
        fprintf(stderr, "state_fuzz: %s: its own state could not be taken and serialised\n", f->id);
        exit(2);
    }
}

/* Every single-bit flip of the serialised state is refused by fmi2DeSerializeFMUstate. */
static void flip_serialised(Fmu *f)
{
    fmi2Byte *copy = calloc(f->n_bytes + 8, 1); /* room for the longer wrong lengths below: the host's buffer */
    memcpy(copy, f->bytes, f->n_bytes);
    long tried = 0, accepted = 0;
    for (size_t bit = 0; bit < 8 * f->n_bytes; bit++) {
        copy[bit / 8] ^= (fmi2Byte)(1u << (bit % 8));
        fmi2FMUstate s = NULL;
        if (f->deserialize(f->c, copy, f->n_bytes, &s) != fmi2Error || s != NULL) {
            accepted++;
            if (s != NULL) f->free_state(f->c, &s);
        }
        copy[bit / 8] ^= (fmi2Byte)(1u << (bit % 8));
        tried++;
    }
    /* wrong lengths: every length from 0 to the true one plus 8 but the true one */
    for (size_t n = 0; n <= f->n_bytes + 8; n++) {
        if (n == f->n_bytes) continue;
        fmi2FMUstate s = NULL;
        if (f->deserialize(f->c, copy, n, &s) != fmi2Error || s != NULL) accepted++;
        tried++;
    }
    free(copy);
    report(f, "serialised_bit_flips_and_lengths", tried, accepted);
}

/* Every single-bit flip of the in-memory state is refused by fmi2SetFMUstate (the state's length: see
   in_memory_bytes). */
static void flip_in_memory(Fmu *f)
{
    unsigned char *p = (unsigned char *)f->state;
    size_t n = f->in_memory_bytes >= 0 ? (size_t)f->in_memory_bytes : f->n_bytes - 16;
    long tried = 0, accepted = 0;
    for (size_t bit = 0; bit < 8 * n; bit++) {
        p[bit / 8] ^= (unsigned char)(1u << (bit % 8));
        if (f->set_state(f->c, f->state) != fmi2Error) accepted++;
        fmi2Byte dummy[1];
        if (f->serialize(f->c, f->state, dummy, 1) != fmi2Error) accepted++;
        p[bit / 8] ^= (unsigned char)(1u << (bit % 8));
        tried += 2;
    }
    report(f, "in_memory_bit_flips", tried, accepted);
}

/* Another FMU's state, bytes and instance are refused (and not touched). */
static void cross(Fmu *f, Fmu *other)
{
    long tried = 0, accepted = 0;
    size_t size = 0;
    fmi2Byte *buf = malloc(other->n_bytes + 64);
    fmi2FMUstate foreign = other->state, s = NULL;
    accepted += f->set_state(f->c, foreign) != fmi2Error;
    accepted += f->serialized_size(f->c, foreign, &size) != fmi2Error;
    accepted += f->serialize(f->c, foreign, buf, other->n_bytes) != fmi2Error;
    accepted += f->free_state(f->c, &foreign) != fmi2Error || foreign != other->state;
    accepted += f->deserialize(f->c, other->bytes, other->n_bytes, &s) != fmi2Error || s != NULL;
    accepted += f->get_state(f->c, &foreign) != fmi2Error || foreign != other->state; /* overwrite a foreign one */
    fmi2Real t = 0.0;
    fmi2ValueReference vr = 0;
    accepted += f->do_step(other->c, 0.0, 1e-3, fmi2True) != fmi2Error;
    accepted += f->get_real(other->c, &vr, 1, &t) != fmi2Error;
    f->free_instance(other->c); /* not this FMU's instance: nothing happens */
    tried += 9;
    /* the other FMU's state and instance are intact */
    accepted += other->set_state(other->c, other->state) != fmi2OK;
    tried++;
    free(buf);
    report(f, "foreign_state_bytes_instance", tried, accepted);
}

/* A freed state is refused by set, serialise and a second free; the FMU's own states still restore it exactly. */
static void freed_and_sound(Fmu *f)
{
    long tried = 0, accepted = 0;
    fmi2FMUstate s = NULL, dangling;
    if (f->get_state(f->c, &s) != fmi2OK) accepted++;
    dangling = s;
    if (f->free_state(f->c, &s) != fmi2OK || s != NULL) accepted++;
    size_t size = 0;
    accepted += f->set_state(f->c, dangling) != fmi2Error;
    accepted += f->serialized_size(f->c, dangling, &size) != fmi2Error;
    accepted += f->free_state(f->c, &dangling) != fmi2Error;
    accepted += f->set_state(f->c, NULL) != fmi2Error;
    tried += 6;
    report(f, "freed_or_null_state", tried, accepted);

    /* sound states are accepted: the state taken after STEPS steps, and its serialised bytes, restore the outputs
       after more steps */
    long refused = 0;
    fmi2ValueReference vr[1] = {0};
    fmi2Real before = 0, after = 0, again = 0;
    fmi2Status got = f->get_real(f->c, vr, 1, &before);
    for (int k = STEPS; k < STEPS + 3; k++) f->do_step(f->c, k * 1e-3, 1e-3, fmi2True);
    refused += f->set_state(f->c, f->state) != fmi2OK;
    refused += got == fmi2OK && (f->get_real(f->c, vr, 1, &after) != fmi2OK || after != before);
    fmi2FMUstate back = NULL;
    refused += f->deserialize(f->c, f->bytes, f->n_bytes, &back) != fmi2OK;
    for (int k = STEPS; k < STEPS + 3; k++) f->do_step(f->c, k * 1e-3, 1e-3, fmi2True);
    refused += f->set_state(f->c, back) != fmi2OK;
    refused += got == fmi2OK && (f->get_real(f->c, vr, 1, &again) != fmi2OK || again != before);
    refused += f->free_state(f->c, &back) != fmi2OK;
    report(f, "sound_state_refused", 6, refused);
}

/* fmi2FreeInstance twice, then calls on the freed instance: refused, nothing read. States left are freed with
   the instance. */
static void free_twice(Fmu *f)
{
    long accepted = 0;
    fmi2FMUstate leftover = NULL;
    f->get_state(f->c, &leftover); /* left for fmi2FreeInstance to free */
    f->free_instance(f->c);
    f->free_instance(f->c);
    accepted += f->do_step(f->c, 0.0, 1e-3, fmi2True) != fmi2Error;
    accepted += f->set_state(f->c, f->state) != fmi2Error;
    report(f, "freed_instance", 2, accepted);
}

int main(int argc, char **argv)
{
    if (argc < 2 || argc - 1 > MAX_FMUS) {
        fprintf(stderr, "usage: state_fuzz LIB,DIR,GUID [LIB,DIR,GUID ...]\n");
        return 2;
    }
    static Fmu fmus[MAX_FMUS];
    int n = argc - 1;
    for (int i = 0; i < n; i++) load(&fmus[i], argv[i + 1]);
    for (int i = 0; i < n; i++) {
        flip_serialised(&fmus[i]);
        flip_in_memory(&fmus[i]);
        for (int j = 0; j < n; j++)
            if (j != i) cross(&fmus[i], &fmus[j]);
        freed_and_sound(&fmus[i]);
    }
    for (int i = 0; i < n; i++) free_twice(&fmus[i]);
    for (int i = 0; i < n; i++) free(fmus[i].bytes);
    printf("messages %ld\n", n_messages);
    return failures;
}
