/* FMU states: get, set, free, (de)serialise (see fmi2_shim.c). */
#include "fmi2_shim.h"

#include <stddef.h>

static uint64_t fnv1a(const void *p, size_t n);

static uint64_t state_checksum(const State *w) { return fnv1a(w, offsetof(State, seal)); }

static void seal_state(State *w) { w->seal = state_checksum(w); }

State *as_state(fmi2FMUstate p)
{
    if (p == NULL || !live_contains(&shim_states, p)) return NULL;
    State *w = (State *)p;
    return (w->magic == STATE_MAGIC && w->seal == state_checksum(w)) ? w : NULL;
}

/* A new wrapper for pythonfmu's state `inner`, made by instance s and registered as live; NULL (inner freed,
   logged as fn) when out of memory. */
static State *new_state(Instance *s, const char *fn, fmi2FMUstate inner)
{
    State *w = calloc(1, sizeof *w);
    if (w == NULL || live_add(&shim_states, w, s) != 0) {
        free(w);
        api.freeFMUstate(s->inner, &inner);
        shim_log(s, fmi2Error, "%s: out of memory", fn);
        return NULL;
    }
    return w;
}

/* -- FMU state -------------------------------------------------------------------------- */
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2GetFMUstate", LIVE, &r);
    if (s == NULL) return r;
    State *w = NULL;
    if (FMUstate == NULL || (*FMUstate != NULL && (w = as_state(*FMUstate)) == NULL)) {
        shim_log(s, fmi2Error, "fmi2GetFMUstate: FMUstate must point to NULL or to a state of this FMU");
        return fmi2Error;
    }
    fmi2FMUstate inner = NULL;
    r = outcome(s, "fmi2GetFMUstate", api.getFMUstate(s->inner, &inner));
    if (r >= fmi2Error) {
        if (inner != NULL && r != fmi2Fatal) api.freeFMUstate(s->inner, &inner);
        return r;
    }
    if (w != NULL) { /* overwrite the given state, as FMI 2.0 allows */
        api.freeFMUstate(s->inner, &w->inner);
    } else if ((w = new_state(s, "fmi2GetFMUstate", inner)) == NULL) {
        return fmi2Error;
    }
    w->magic = STATE_MAGIC;
    w->inner = inner;
    w->state = s->state;
    w->start_time = s->start_time;
    w->last_successful_time = s->last_successful_time;
    seal_state(w);
    *FMUstate = w;
    return r;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate)
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2SetFMUstate", LIVE, &r);
    if (s == NULL) return r;
    State *w = as_state(FMUstate);
    if (w == NULL) {
        shim_log(s, fmi2Error, "fmi2SetFMUstate: not a live state of this FMU (NULL, freed, or another FMU's)");
        return fmi2Error;
    }
    r = outcome(s, "fmi2SetFMUstate", api.setFMUstate(s->inner, w->inner));
    if (r <= fmi2Warning) {
        s->state = w->state;
        s->start_time = w->start_time;
        s->last_successful_time = w->last_successful_time;
    }
    return r;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2FreeFMUstate", LIVE, &r);
    if (s == NULL) return r;
    if (FMUstate == NULL || *FMUstate == NULL) return fmi2OK; /* nothing to free */
    State *w = as_state(*FMUstate);
    if (w == NULL) {
        shim_log(s, fmi2Error, "fmi2FreeFMUstate: not a state of this FMU (freed twice?)");
        return fmi2Error;
    }
    live_remove(&shim_states, w);
    r = outcome(s, "fmi2FreeFMUstate", api.freeFMUstate(s->inner, &w->inner));
    w->magic = 0;
    free(w);
    *FMUstate = NULL;
    return r;
}

/* Serialized state: "FXS1", uint32 state, double start time, double last successful time, uint64 seal, then
   pythonfmu's payload (JSON). The seal is the FNV-1a hash of this FMU's GUID (one per build), the 24 bytes before
   the seal and the payload: a flipped bit anywhere, or another FMU's or build's bytes, are refused. */
static uint64_t fnv1a_more(uint64_t h, const void *p, size_t n)
{
    const unsigned char *b = p;
    for (size_t i = 0; i < n; i++) h = (h ^ b[i]) * 1099511628211ull;
    return h;
}

static uint64_t fnv1a(const void *p, size_t n) { return fnv1a_more(1469598103934665603ull, p, n); }

static uint64_t serial_seal(const fmi2Byte *bytes, size_t size)
{
    uint64_t h = fnv1a(FLEXARM_FMU_GUID, sizeof FLEXARM_FMU_GUID);
    h = fnv1a_more(h, bytes, 24);
    return fnv1a_more(h, bytes + SERIAL_HEADER, size - SERIAL_HEADER);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size)
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2SerializedFMUstateSize", LIVE, &r);
    if (s == NULL) return r;
    State *w = as_state(FMUstate);
    if (w == NULL || size == NULL) {
        shim_log(s, fmi2Error, "fmi2SerializedFMUstateSize: needs a state of this FMU and a size pointer");
        return fmi2Error;
    }
    size_t n = 0;
    r = outcome(s, "fmi2SerializedFMUstateSize", api.serializedFMUstateSize(s->inner, w->inner, &n));
    if (r <= fmi2Warning) *size = n + SERIAL_HEADER;
    return r;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size)
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2SerializeFMUstate", LIVE, &r);
    if (s == NULL) return r;
    State *w = as_state(FMUstate);
    if (w == NULL || serializedState == NULL) {
        shim_log(s, fmi2Error, "fmi2SerializeFMUstate: needs a state of this FMU and a buffer");
        return fmi2Error;
    }
    size_t n = 0;
    r = outcome(s, "fmi2SerializeFMUstate", api.serializedFMUstateSize(s->inner, w->inner, &n));
    if (r >= fmi2Error) return r;
    if (size != n + SERIAL_HEADER) { /* pythonfmu would copy `size` bytes whatever the payload's length */
        shim_log(s, fmi2Error, "fmi2SerializeFMUstate: size %zu differs from fmi2SerializedFMUstateSize (%zu)",
                 size, n + SERIAL_HEADER);
        return fmi2Error;
    }
    r = outcome(s, "fmi2SerializeFMUstate", api.serializeFMUstate(s->inner, w->inner, serializedState + SERIAL_HEADER,
                                                                 n));
    if (r >= fmi2Error) return r;
    uint32_t st = (uint32_t)w->state;
    memcpy(serializedState, SERIAL_MAGIC, 4);
    memcpy(serializedState + 4, &st, 4);
    memcpy(serializedState + 8, &w->start_time, 8);
    memcpy(serializedState + 16, &w->last_successful_time, 8);
    uint64_t seal = serial_seal(serializedState, size);
    memcpy(serializedState + 24, &seal, 8);
    return r;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate)
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2DeSerializeFMUstate", LIVE, &r);
    if (s == NULL) return r;
    State *w = NULL;
    if (FMUstate == NULL || (*FMUstate != NULL && (w = as_state(*FMUstate)) == NULL)) {
        shim_log(s, fmi2Error, "fmi2DeSerializeFMUstate: FMUstate must point to NULL or to a state of this FMU");
        return fmi2Error;
    }
    uint32_t st = 0;
    uint64_t hash = 0;
    if (serializedState != NULL && size >= SERIAL_HEADER) {
        memcpy(&st, serializedState + 4, 4);
        memcpy(&hash, serializedState + 24, 8);
    }
    /* pythonfmu turns bytes it cannot decode into fmi2Fatal (and frees the instance): check them first. */
    if (serializedState == NULL || size < SERIAL_HEADER || memcmp(serializedState, SERIAL_MAGIC, 4) != 0 ||
        st >= (uint32_t)S_FATAL || hash != serial_seal(serializedState, size)) {
        shim_log(s, fmi2Error, "fmi2DeSerializeFMUstate: the %zu bytes are not a state serialized by %s (wrong "
                 "header, size or checksum: corrupt, or another FMU's or build's); nothing changed", size,
                 FLEXARM_MODEL_IDENTIFIER);
        return fmi2Error;
    }
    fmi2FMUstate inner = NULL;
    r = outcome(s, "fmi2DeSerializeFMUstate",
                api.deSerializeFMUstate(s->inner, serializedState + SERIAL_HEADER, size - SERIAL_HEADER, &inner));
    if (r >= fmi2Error) {
        if (inner != NULL && r != fmi2Fatal) api.freeFMUstate(s->inner, &inner);
        return r;
    }
    if (w != NULL) {
        api.freeFMUstate(s->inner, &w->inner);
    } else if ((w = new_state(s, "fmi2DeSerializeFMUstate", inner)) == NULL) {
        return fmi2Error;
    }
    w->magic = STATE_MAGIC;
    w->inner = inner;
    w->state = (int)st;
    memcpy(&w->start_time, serializedState + 8, 8);
    memcpy(&w->last_successful_time, serializedState + 16, 8);
    seal_state(w);
    *FMUstate = w;
    return r;
}

