/* Sealed FMU states of the native FMUs: get, set, free, (de)serialise (see fmi2_glue_internal.h). */
#include "fmi2_glue_internal.h"

#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* -- FMU state ------------------------------------------------------------------------------ *
 * A state is sealed: it carries the identity of this FMU's build (FNV-1a 64 of the model identifier and the
 * GUID, which hashes the sources and resources), its size and an FNV-1a 64 checksum of its bytes; the
 * serialised form adds a tag and a checksum of the whole. FNV-1a changes on any change of a single byte, so
 * every corrupted bit is found. A handle is used only if it is in glue_live_states (made by this binary, not freed).
 */
typedef struct {
    uint64_t identity; /* state_identity() of the FMU that made it */
    uint64_t size;     /* bytes of the whole snapshot, snapshot_size() */
    uint64_t checksum; /* FNV-1a 64 of identity, size and every byte after this field */
    int32_t fmi_state, outputs_stale, outputs_read, reserved; /* reserved: 0, keeps `time` aligned */
    double time;
    /* followed by values[n_vars], invalid[n_vars], state[state_size] */
} Snapshot;

#define SERIAL_TAG "FNXSTAT3"
#define SERIAL_TAG_SIZE 8
#define FNV_OFFSET 1469598103934665603ull

static uint64_t fnv1a(uint64_t h, const void *data, size_t n)
{
    const unsigned char *p = data;
    for (size_t i = 0; i < n; i++) h = (h ^ p[i]) * 1099511628211ull;
    return h;
}

static uint64_t state_identity(void)
{
    uint64_t h = fnv1a(FNV_OFFSET, MODEL_INFO.model_identifier, strlen(MODEL_INFO.model_identifier) + 1);
    h = fnv1a(h, MODEL_INFO.guid, strlen(MODEL_INFO.guid) + 1);
    return h ? h : 1; /* 0 marks a freed snapshot */
}

static size_t snapshot_size(void)
{
    return sizeof(Snapshot) + MODEL_INFO.n_vars * (sizeof(double) + 1) + MODEL_INFO.state_size;
}

static uint64_t snapshot_checksum(const Snapshot *snap, size_t size)
{
    const unsigned char *p = (const unsigned char *)snap;
    uint64_t h = fnv1a(FNV_OFFSET, p, offsetof(Snapshot, checksum));
    return fnv1a(h, p + offsetof(Snapshot, fmi_state), size - offsetof(Snapshot, fmi_state));
}

static void take_snapshot(const Instance *inst, Snapshot *snap)
{
    unsigned char *p = (unsigned char *)(snap + 1);
    snap->identity = state_identity();
    snap->size = snapshot_size();
    snap->fmi_state = inst->fmi_state;
    snap->outputs_stale = inst->outputs_stale;
    snap->outputs_read = inst->outputs_read; /* what the master did before this state: part of it */
    snap->reserved = 0;
    snap->time = inst->time;
    memcpy(p, inst->values, MODEL_INFO.n_vars * sizeof(double));
    memcpy(p + MODEL_INFO.n_vars * sizeof(double), inst->invalid, MODEL_INFO.n_vars);
    memcpy(p + MODEL_INFO.n_vars * (sizeof(double) + 1), inst->state, MODEL_INFO.state_size);
    snap->checksum = snapshot_checksum(snap, snapshot_size());
}

/* NULL if `snap` (snapshot_size() readable bytes) is a sound state of this FMU's build; else what is wrong. */
static const char *snapshot_problem(const Snapshot *snap)
{
    if (snap->identity != state_identity()) return "it is a state of another FMU or of another build of this one";
    if (snap->size != snapshot_size()) return "its size does not match this FMU's states";
    if (snap->checksum != snapshot_checksum(snap, snapshot_size())) return "its checksum does not match (corrupt)";
    if (snap->fmi_state < 0 || snap->fmi_state >= S_COUNT || (snap->outputs_stale != 0 && snap->outputs_stale != 1) ||
        (snap->outputs_read != 0 && snap->outputs_read != 1) || snap->reserved != 0 ||
        !isfinite(snap->time))
        return "its FMI state, flags or time are out of range";
    const unsigned char *invalid = (const unsigned char *)(snap + 1) + MODEL_INFO.n_vars * sizeof(double);
    for (size_t i = 0; i < MODEL_INFO.n_vars; i++)
        if (invalid[i] > 1) return "its flags are out of range";
    return NULL;
}

static void restore_snapshot(Instance *inst, const Snapshot *snap)
{
    const unsigned char *p = (const unsigned char *)(snap + 1);
    inst->fmi_state = snap->fmi_state;
    inst->outputs_stale = snap->outputs_stale;
    inst->outputs_read = snap->outputs_read;
    inst->time = snap->time;
    memcpy(inst->values, p, MODEL_INFO.n_vars * sizeof(double));
    memcpy(inst->invalid, p + MODEL_INFO.n_vars * sizeof(double), MODEL_INFO.n_vars);
    memcpy(inst->state, p + MODEL_INFO.n_vars * (sizeof(double) + 1), MODEL_INFO.state_size);
}

void glue_free_snapshot(void *snap)
{
    ((Snapshot *)snap)->identity = 0;
    free(snap);
}

/* The live state `handle` of this FMU, checked; NULL after logging why not (as `fn`). */
static const Snapshot *sound_state(Instance *inst, const char *fn, fmi2FMUstate handle)
{
    if (handle == NULL || !live_contains(&glue_live_states, handle)) {
        glue_log(inst, fmi2Error, "%s: FMUstate %p is not a live state of %s (NULL, freed, or another FMU's); "
                 "nothing changed", fn, handle, MODEL_INFO.model_identifier);
        return NULL;
    }
    const Snapshot *snap = handle;
    const char *problem = snapshot_problem(snap);
    if (problem != NULL) {
        glue_log(inst, fmi2Error, "%s: FMUstate refused: %s; nothing changed", fn, problem);
        return NULL;
    }
    return snap;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    Instance *inst = glue_admit(c, F_GET_STATE);
    if (inst == NULL) return fmi2Error;
    if (FMUstate == NULL || (*FMUstate != NULL && !live_contains(&glue_live_states, *FMUstate))) {
        glue_log(inst, fmi2Error, "fmi2GetFMUstate: FMUstate must point to NULL or to a live state of %s",
                 MODEL_INFO.model_identifier);
        return fmi2Error;
    }
    Snapshot *snap = *FMUstate; /* overwritten in place, as FMI 2.0 allows */
    if (snap == NULL) {
        snap = malloc(snapshot_size());
        if (snap == NULL || live_add(&glue_live_states, snap, inst) != 0) {
            free(snap);
            glue_log(inst, fmi2Error, "fmi2GetFMUstate: out of memory");
            return fmi2Error;
        }
    }
    take_snapshot(inst, snap);
    *FMUstate = snap;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate)
{
    Instance *inst = glue_admit(c, F_SET_STATE);
    if (inst == NULL) return fmi2Error;
    const Snapshot *snap = sound_state(inst, "fmi2SetFMUstate", FMUstate);
    if (snap == NULL) return fmi2Error;
    restore_snapshot(inst, snap);
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    Instance *inst = glue_admit(c, F_GET_STATE);
    if (inst == NULL) return fmi2Error;
    if (FMUstate == NULL || *FMUstate == NULL) return fmi2OK; /* nothing to free */
    if (!live_remove(&glue_live_states, *FMUstate)) {
        glue_log(inst, fmi2Error, "fmi2FreeFMUstate: FMUstate %p is not a live state of %s (freed twice, or "
                 "another FMU's); nothing freed", *FMUstate, MODEL_INFO.model_identifier);
        return fmi2Error;
    }
    glue_free_snapshot(*FMUstate);
    *FMUstate = NULL;
    return fmi2OK;
}

/* Serialised: SERIAL_TAG, the snapshot (with its identity, size and checksum), then FNV-1a 64 of all before. */
#define SERIAL_SIZE() (SERIAL_TAG_SIZE + snapshot_size() + 8)

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size)
{
    Instance *inst = glue_admit(c, F_SERIALIZE);
    if (inst == NULL) return fmi2Error;
    if (size == NULL) {
        glue_log(inst, fmi2Error, "fmi2SerializedFMUstateSize: size is NULL");
        return fmi2Error;
    }
    if (sound_state(inst, "fmi2SerializedFMUstateSize", FMUstate) == NULL) return fmi2Error;
    *size = SERIAL_SIZE();
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size)
{
    Instance *inst = glue_admit(c, F_SERIALIZE);
    if (inst == NULL) return fmi2Error;
    const Snapshot *snap = sound_state(inst, "fmi2SerializeFMUstate", FMUstate);
    if (snap == NULL) return fmi2Error;
    if (serializedState == NULL || size != SERIAL_SIZE()) {
        glue_log(inst, fmi2Error, "fmi2SerializeFMUstate: the buffer must be %zu bytes (fmi2SerializedFMUstateSize), "
                 "not %zu%s", SERIAL_SIZE(), size, serializedState == NULL ? " at NULL" : "");
        return fmi2Error;
    }
    size_t n = snapshot_size();
    memcpy(serializedState, SERIAL_TAG, SERIAL_TAG_SIZE);
    memcpy(serializedState + SERIAL_TAG_SIZE, snap, n);
    uint64_t sum = fnv1a(FNV_OFFSET, serializedState, SERIAL_TAG_SIZE + n);
    memcpy(serializedState + SERIAL_TAG_SIZE + n, &sum, 8);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate)
{
    Instance *inst = glue_admit(c, F_SERIALIZE);
    if (inst == NULL) return fmi2Error;
    if (serializedState == NULL || FMUstate == NULL) {
        glue_log(inst, fmi2Error, "fmi2DeSerializeFMUstate: serializedState and FMUstate must not be NULL");
        return fmi2Error;
    }
    size_t n = snapshot_size();
    const char *problem = NULL;
    uint64_t sum = 0;
    if (size != SERIAL_SIZE()) problem = "its length is not that of this FMU's states";
    else if (memcmp(serializedState, SERIAL_TAG, SERIAL_TAG_SIZE) != 0) problem = "it does not start with " SERIAL_TAG;
    else if (memcpy(&sum, serializedState + SERIAL_TAG_SIZE + n, 8),
             sum != fnv1a(FNV_OFFSET, serializedState, SERIAL_TAG_SIZE + n))
        problem = "its checksum does not match (corrupt)";
    Snapshot *snap = NULL;
    if (problem == NULL) {
        snap = malloc(n);
        if (snap == NULL) problem = "out of memory";
        else {
            memcpy(snap, serializedState + SERIAL_TAG_SIZE, n);
            problem = snapshot_problem(snap);
        }
    }
    if (problem == NULL && live_add(&glue_live_states, snap, inst) != 0) problem = "out of memory";
    if (problem != NULL) {
        free(snap);
        glue_log(inst, fmi2Error, "fmi2DeSerializeFMUstate: %zu bytes refused as a state of %s (this build): %s",
                 size, MODEL_INFO.model_identifier, problem);
        return fmi2Error;
    }
    *FMUstate = snap;
    return fmi2OK;
}
