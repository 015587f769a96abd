/*
 * FMI 2.0 co-simulation front end of this project's FMUs (the "shim").
 *
 * fmu_build compiles this file with fmi2_shim_python.c and fmi2_shim_state.c once per FMU into
 * binaries/linux64/<modelIdentifier>.so and puts pythonfmu 0.7.0's own binary
 * beside it as binaries/linux64/libpythonfmu-export.so. The host loads the
 * shim; the shim loads pythonfmu's binary (RTLD_LOCAL) and forwards every
 * call to it, adding what pythonfmu cannot do from Python:
 *
 *  - The FMI 2.0 co-simulation state machine (instantiated, initializationMode,
 *    stepComplete, stepFailed, terminated, fatal). A call that is not allowed
 *    in the current state is not forwarded: it returns fmi2Error with a log
 *    message naming the call, the state and the states that allow it.
 *  - fmi2Error from Python. pythonfmu maps a Python exception to fmi2Fatal
 *    (and frees the Python object) and `do_step() -> False` to fmi2Discard;
 *    nothing gives fmi2Error. The Python glue (flexarm_fmu_base.py) therefore
 *    logs every failure at status fmi2Error; pythonfmu delivers the slave's
 *    log through the logger callback *during* the call, and the shim passes
 *    pythonfmu its own logger. The status of a call is the worst of
 *    pythonfmu's return value and an error logged during the call (a
 *    logged warning is passed on, the status stays): a rejected value, a
 *    refused step or a failed initialisation returns fmi2Error;
 *    fmi2Discard remains only for a step the glue discards without an
 *    error (a smaller step may succeed).
 *  - fmi2Error leaves the instance in the state it was in: our FMUs reject a
 *    value or refuse a step before changing anything, so the master may fix
 *    the value and go on (or reset, or free, as FMI 2.0 prescribes).
 *  - Argument checks pythonfmu lacks (GUID, fmuType, NULL pointers, start and
 *    stop time, FMU-state buffers with a header and checksum), the
 *    fmi2Get*Status functions, fmi2GetFMUstate into an existing state, and
 *    file URIs of any form for the resources.
 *  - Python in a native host: if no Python is loaded in the process, the shim
 *    loads the libpython it was built for (FLEXARM_LIBPYTHON, from the building
 *    Python's sysconfig; or $FLEXARM_FMU_LIBPYTHON) with RTLD_GLOBAL
 *    before pythonfmu's binary, which needs its symbols; if that fails, the
 *    log says what to do instead of the host failing in dlopen. It also
 *    starts the interpreter itself (without signal handlers).
 *  - A pre-flight import of the slave module before pythonfmu's: pythonfmu
 *    0.7.0 crashes the host (it releases an uninitialised pointer) when the
 *    module cannot be imported, e.g. NumPy missing, or modules cached from
 *    an FMU folder a host has deleted since (fmpy's simulate_fmu run twice).
 *    The shim drops such stale modules, imports the slave module, and on
 *    failure logs the traceback and returns NULL from fmi2Instantiate.
 *
 * Log messages with status warning or worse always reach the host's logger;
 * others only with loggingOn (and the categories of fmi2SetDebugLogging).
 * '%' is doubled, as the logger's message is a printf format.
 */
#include "fmi2_shim.h"

const char *const STATE_NAMES[S_COUNT] = {"instantiated", "initializationMode", "stepComplete", "stepFailed",
                                          "terminated", "fatal"};
/* pythonfmu's <LogCategories> (Fmi2Slave.log_categories), the only valid debug categories. */
const char *const CATEGORIES[N_CATEGORIES] = {"logStatusWarning", "logStatusDiscard", "logStatusError",
                                              "logStatusFatal", "logAll"};

LiveTable shim_instances, shim_states;

Instance *as_instance(fmi2Component c)
{
    if (c == NULL || !live_contains(&shim_instances, c)) return NULL;
    Instance *s = (Instance *)c;
    return s->magic == INSTANCE_MAGIC ? s : NULL;
}

/* -- logging -------------------------------------------------------------------------- */
static const char *status_category(fmi2Status status)
{
    switch (status) {
    case fmi2Warning: return "logStatusWarning";
    case fmi2Discard: return "logStatusDiscard";
    case fmi2Error: return "logStatusError";
    case fmi2Fatal: return "logStatusFatal";
    default: return "logAll";
    }
}

static int category_index(const char *category)
{
    for (size_t i = 0; i < N_CATEGORIES; i++)
        if (category != NULL && strcmp(category, CATEGORIES[i]) == 0) return (int)i;
    return -1;
}

/* Pass one message to the host's logger (text, not a format: '%' is doubled). */
void emit(Instance *s, fmi2Status status, const char *category, const char *text)
{
    if (s->host_logger == NULL) return;
    if (category == NULL || *category == '\0') category = status_category(status);
    if (status == fmi2OK) { /* debug output: only when asked for, in the categories asked for */
        int i = category_index(category);
        unsigned log_all = 1u << (N_CATEGORIES - 1);
        if (!s->logging_on) return;
        if (!(s->category_mask & log_all) && (i < 0 || !(s->category_mask & (1u << i)))) return;
    }
    size_t n = strlen(text), extra = 0;
    for (size_t i = 0; i < n; i++) extra += text[i] == '%';
    char *escaped = malloc(n + extra + 1);
    if (escaped == NULL) return;
    char *o = escaped;
    for (size_t i = 0; i < n; i++) {
        *o++ = text[i];
        if (text[i] == '%') *o++ = '%';
    }
    *o = '\0';
    s->host_logger(s->host_env, s->name, status, category, escaped);
    free(escaped);
}

/* A message of the shim itself, prefixed with the instance name like the glue's. */
__attribute__((format(printf, 3, 4))) void shim_log(Instance *s, fmi2Status status, const char *fmt, ...)
{
    char body[4096];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(body, sizeof body, fmt, ap);
    va_end(ap);
    size_t n = strlen(s->name) + strlen(body) + 3;
    char *text = malloc(n);
    if (text == NULL) return;
    snprintf(text, n, "%s: %s", s->name, body);
    emit(s, status, NULL, text);
    free(text);
}

/* The logger given to pythonfmu: remembers the worst status of the call, forwards the message. */
void inner_logger(fmi2ComponentEnvironment env, fmi2String instanceName, fmi2Status status,
                         fmi2String category, fmi2String message, ...)
{
    (void)instanceName;
    Instance *s = (Instance *)env;
    if (s == NULL) return;
    if (status > s->worst && status != fmi2Pending) s->worst = status;
    emit(s, status, category, message != NULL ? message : "");
}

/* -- state machine -------------------------------------------------------------------- */
static void allowed_list(unsigned allowed, char *buf, size_t size)
{
    buf[0] = '\0';
    for (int st = 0; st < S_COUNT; st++) {
        if (!(allowed & M(st))) continue;
        size_t len = strlen(buf);
        snprintf(buf + len, size - len, "%s%s", len ? ", " : "", STATE_NAMES[st]);
    }
}

static const char *hint(int state)
{
    switch (state) {
    case S_INSTANTIATED: return "; initialise first (fmi2SetupExperiment, fmi2EnterInitializationMode, "
                                "fmi2ExitInitializationMode)";
    case S_INIT: return "; leave initialisation mode first (fmi2ExitInitializationMode)";
    case S_STEP_FAILED: return "; the last fmi2DoStep was discarded: restore a state with fmi2SetFMUstate, "
                               "or call fmi2Reset or fmi2Terminate";
    case S_TERMINATED: return "; the instance was terminated: call fmi2Reset to use it again";
    default: return "";
    }
}

/*
 * Admit a call: returns the instance, or NULL with *refusal set (after logging
 * why) if the component is invalid or the call is not allowed in its state.
 */
Instance *admit(fmi2Component c, const char *fn, unsigned allowed, fmi2Status *refusal)
{
    Instance *s = as_instance(c);
    if (s == NULL) { /* no logger to tell: an unknown or freed component */
        *refusal = fmi2Error;
        return NULL;
    }
    if (s->state == S_FATAL) {
        shim_log(s, fmi2Fatal, "%s: the instance is unusable after an earlier fmi2Fatal; free it", fn);
        *refusal = fmi2Fatal;
        return NULL;
    }
    if (!(allowed & M(s->state))) {
        char list[160];
        allowed_list(allowed, list, sizeof list);
        shim_log(s, fmi2Error, "%s is not allowed in state '%s' (allowed in: %s)%s; the call was ignored", fn,
                 STATE_NAMES[s->state], list, hint(s->state));
        *refusal = fmi2Error;
        return NULL;
    }
    s->worst = fmi2OK;
    return s;
}

/* Status of a forwarded call: pythonfmu's, raised to fmi2Error when the Python slave logged an error during
 * it. A logged warning leaves the status as it was, as in the native kind: the master sees the message, and
 * the step goes on in masters that take fmi2Warning for a failed step (OMSimulator stops there). */
fmi2Status outcome(Instance *s, const char *fn, fmi2Status inner)
{
    fmi2Status r = inner;
    if (s->worst >= fmi2Error && r < fmi2Error) r = fmi2Error;
    if (r == fmi2Fatal && s->state != S_FATAL) {
        s->state = S_FATAL;
        shim_log(s, fmi2Fatal, "%s: pythonfmu returned fmi2Fatal; the instance cannot be used any more", fn);
    }
    return r;
}

int null_arrays(Instance *s, const char *fn, size_t nvr, const void *vr, const void *value)
{
    if (nvr > 0 && (vr == NULL || value == NULL)) {
        shim_log(s, fmi2Error, "%s: vr[] and value[] must not be NULL when nvr = %zu; the call was ignored", fn,
                 nvr);
        return 1;
    }
    return 0;
}

/* =========================================================================================
 * FMI 2.0 functions
 * ========================================================================================= */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

/*
 * pythonfmu 0.7.0 delivers the Python slave's queued log messages at the end of every call, except after
 * creating the slave object (fmi2Instantiate, fmi2Reset): what the slave's __init__ logs stays queued. Its
 * fmi2FreeInstance deletes its logger object before the slave (C++ member order in Fmi2Component), and the
 * slave's destructor then delivers the queue through the deleted logger: a use-after-free that crashed hosts
 * freeing an instance they never initialised (a master whose wiring fails). An empty fmi2GetReal right after
 * the slave object is made delivers the queue while the logger is alive, in the call that caused it.
 */
static fmi2Status deliver_queued_log(Instance *s)
{
    fmi2ValueReference vr = 0;
    fmi2Real value = 0.0;
    return api.getReal(s->inner, &vr, 0, &value); /* the slave's get_real([]): no effect in instantiated mode */
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    Instance *s = calloc(1, sizeof *s);
    if (s == NULL) return NULL;
    s->magic = INSTANCE_MAGIC;
    s->state = S_INSTANTIATED;
    s->host_logger = functions != NULL ? functions->logger : NULL;
    s->host_env = functions != NULL ? functions->componentEnvironment : NULL;
    s->name = strdup(instanceName != NULL ? instanceName : "");
    s->logging_on = loggingOn != fmi2False;
    s->category_mask = (1u << N_CATEGORIES) - 1u;
    s->start_time = 0.0;
    s->last_successful_time = NAN;
    if (s->name == NULL) {
        free(s);
        return NULL;
    }
    if (instanceName == NULL || *instanceName == '\0') {
        shim_log(s, fmi2Error, "fmi2Instantiate: instanceName must be a non-empty string");
        goto fail;
    }
    if (fmuType != fmi2CoSimulation) {
        shim_log(s, fmi2Error, "fmi2Instantiate: fmuType %d requested, but %s is a co-simulation FMU only "
                 "(fmi2CoSimulation = %d)", (int)fmuType, FLEXARM_MODEL_IDENTIFIER, (int)fmi2CoSimulation);
        goto fail;
    }
    if (fmuGUID == NULL || strcmp(fmuGUID, FLEXARM_FMU_GUID) != 0) {
        shim_log(s, fmi2Error, "fmi2Instantiate: fmuGUID '%s' does not match this FMU's '%s' (a modelDescription.xml "
                 "of another build?)", fmuGUID != NULL ? fmuGUID : "(null)", FLEXARM_FMU_GUID);
        goto fail;
    }
    char *resources = resources_path(s, fmuResourceLocation);
    if (resources == NULL) {
        shim_log(s, fmi2Error, "fmi2Instantiate: fmuResourceLocation '%s' is not a local file URI",
                 fmuResourceLocation != NULL ? fmuResourceLocation : "(null)");
        goto fail;
    }
    if (load_api(s) != 0 || preflight(s, resources) != 0) {
        free(resources);
        goto fail;
    }
    s->inner_callbacks.logger = inner_logger;
    s->inner_callbacks.allocateMemory = calloc;
    s->inner_callbacks.freeMemory = free;
    s->inner_callbacks.stepFinished = NULL;
    s->inner_callbacks.componentEnvironment = s;
    s->worst = fmi2OK;
    /* Logging on inside: the shim needs every message to see errors; it filters for the host. */
    s->inner = api.instantiate(instanceName, fmi2CoSimulation, fmuGUID, resources, &s->inner_callbacks, visible,
                               fmi2True);
    free(resources);
    if (s->inner == NULL) {
        shim_log(s, fmi2Error, "fmi2Instantiate: pythonfmu could not create the Python slave (see the messages "
                 "above); are numpy and scipy importable by this Python (PYTHONPATH)?");
        goto fail;
    }
    if (deliver_queued_log(s) == fmi2Fatal) { /* pythonfmu released the slave: freeing it would crash */
        shim_log(s, fmi2Error, "fmi2Instantiate: the Python slave failed right after it was created (see the "
                 "messages above)");
        goto fail;
    }
    if (live_add(&shim_instances, s, NULL) != 0) {
        shim_log(s, fmi2Error, "fmi2Instantiate: out of memory");
        api.freeInstance(s->inner);
        goto fail;
    }
    return s;
fail:
    free_instance_memory(s);
    return NULL;
}

void fmi2FreeInstance(fmi2Component c)
{
    Instance *s = as_instance(c);
    if (s == NULL) return; /* NULL, freed already, or not an instance of this FMU: nothing to do */
    live_remove(&shim_instances, s);
    for (State *w; (w = live_take_owned(&shim_states, s)) != NULL;) { /* the states it made go with it */
        if (s->state != S_FATAL) api.freeFMUstate(s->inner, &w->inner);
        w->magic = 0;
        free(w);
    }
    if (s->state == S_FATAL) /* pythonfmu already released its Python objects; its destructor would again */
        shim_log(s, fmi2Warning, "fmi2FreeInstance: pythonfmu's part of this instance is not freed after "
                 "fmi2Fatal (freeing it would crash the process)");
    else
        api.freeInstance(s->inner);
    free_instance_memory(s);
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[])
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2SetDebugLogging", LIVE, &r);
    if (s == NULL) return r;
    if (nCategories > 0 && categories == NULL) {
        shim_log(s, fmi2Error, "fmi2SetDebugLogging: categories[] must not be NULL when nCategories = %zu",
                 nCategories);
        return fmi2Error;
    }
    unsigned mask = nCategories == 0 ? (1u << N_CATEGORIES) - 1u : 0u;
    for (size_t i = 0; i < nCategories; i++) {
        int k = category_index(categories[i]);
        if (k < 0) {
            shim_log(s, fmi2Error, "fmi2SetDebugLogging: unknown log category '%s' (known: logStatusWarning, "
                     "logStatusDiscard, logStatusError, logStatusFatal, logAll); nothing changed",
                     categories[i] != NULL ? categories[i] : "(null)");
            return fmi2Error;
        }
        mask |= 1u << k;
    }
    s->logging_on = loggingOn != fmi2False;
    s->category_mask = mask;
    return fmi2OK;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2SetupExperiment", M(S_INSTANTIATED), &r);
    if (s == NULL) return r;
    if (!isfinite(startTime) || (stopTimeDefined && !(isfinite(stopTime) && stopTime >= startTime)) ||
        (toleranceDefined && !(isfinite(tolerance) && tolerance > 0.0))) {
        shim_log(s, fmi2Error, "fmi2SetupExperiment: startTime must be finite, stopTime (if defined) finite and "
                 ">= startTime, tolerance (if defined) finite and > 0; got startTime = %.17g, stopTime = %.17g "
                 "(defined: %d), tolerance = %.17g (defined: %d); the call was ignored",
                 startTime, stopTime, (int)stopTimeDefined, tolerance, (int)toleranceDefined);
        return fmi2Error;
    }
    r = outcome(s, "fmi2SetupExperiment",
                api.setupExperiment(s->inner, toleranceDefined, tolerance, startTime, stopTimeDefined, stopTime));
    if (r <= fmi2Warning) s->start_time = startTime;
    return r;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2EnterInitializationMode", M(S_INSTANTIATED), &r);
    if (s == NULL) return r;
    r = outcome(s, "fmi2EnterInitializationMode", api.enterInitializationMode(s->inner));
    if (r <= fmi2Warning) s->state = S_INIT;
    return r;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2ExitInitializationMode", M(S_INIT), &r);
    if (s == NULL) return r;
    r = outcome(s, "fmi2ExitInitializationMode", api.exitInitializationMode(s->inner));
    if (r <= fmi2Warning) { /* on error the FMU stays in initialisation mode: fix the value, try again */
        s->state = S_STEP_COMPLETE;
        s->last_successful_time = s->start_time;
    }
    return r;
}

fmi2Status fmi2Terminate(fmi2Component c)
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2Terminate", M(S_STEP_COMPLETE) | M(S_STEP_FAILED), &r);
    if (s == NULL) return r;
    r = outcome(s, "fmi2Terminate", api.terminate(s->inner));
    if (r <= fmi2Warning) s->state = S_TERMINATED;
    return r;
}

fmi2Status fmi2Reset(fmi2Component c)
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2Reset", LIVE, &r);
    if (s == NULL) return r;
    r = api.reset(s->inner); /* pythonfmu makes a new Python slave object */
    if (r <= fmi2Warning) {
        fmi2Status delivered = deliver_queued_log(s);
        if (delivered > r) r = delivered;
    }
    r = outcome(s, "fmi2Reset", r);
    if (r <= fmi2Warning) {
        s->state = S_INSTANTIATED;
        s->start_time = 0.0;
        s->last_successful_time = NAN;
    }
    return r;
}

/* -- getters and setters ------------------------------------------------------------- */
#define GETTER(NAME, FIELD, TYPE)                                                                             \
    fmi2Status NAME(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, TYPE value[])                \
    {                                                                                                         \
        fmi2Status r;                                                                                         \
        Instance *s = admit(c, #NAME, GETTABLE, &r);                                                          \
        if (s == NULL) return r;                                                                              \
        if (null_arrays(s, #NAME, nvr, vr, value)) return fmi2Error;                                          \
        return outcome(s, #NAME, api.FIELD(s->inner, vr, nvr, value));                                        \
    }

GETTER(fmi2GetReal, getReal, fmi2Real)
GETTER(fmi2GetInteger, getInteger, fmi2Integer)
GETTER(fmi2GetBoolean, getBoolean, fmi2Boolean)
GETTER(fmi2GetString, getString, fmi2String)

#define SETTER(NAME, FIELD, TYPE)                                                                             \
    fmi2Status NAME(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const TYPE value[])          \
    {                                                                                                         \
        fmi2Status r;                                                                                         \
        Instance *s = admit(c, #NAME, SETTABLE, &r);                                                          \
        if (s == NULL) return r;                                                                              \
        if (null_arrays(s, #NAME, nvr, vr, value)) return fmi2Error;                                          \
        return outcome(s, #NAME, api.FIELD(s->inner, vr, nvr, value));                                       \
    }

SETTER(fmi2SetReal, setReal, fmi2Real)
SETTER(fmi2SetInteger, setInteger, fmi2Integer)
SETTER(fmi2SetBoolean, setBoolean, fmi2Boolean)

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[])
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2SetString", SETTABLE, &r);
    if (s == NULL) return r;
    if (null_arrays(s, "fmi2SetString", nvr, vr, value)) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        if (value[i] == NULL) { /* pythonfmu would pass None to Python */
            shim_log(s, fmi2Error, "fmi2SetString: value[%zu] (vr %u) is NULL; the call was ignored", i,
                     (unsigned)vr[i]);
            return fmi2Error;
        }
    }
    return outcome(s, "fmi2SetString", api.setString(s->inner, vr, nvr, value));
}

/* -- what this FMU does not support (capability flags false in modelDescription.xml) ------- */
static fmi2Status unsupported(fmi2Component c, const char *fn, const char *why)
{
    fmi2Status r;
    Instance *s = admit(c, fn, LIVE, &r);
    if (s == NULL) return r;
    shim_log(s, fmi2Error, "%s is not supported by this FMU (%s)", fn, why);
    return fmi2Error;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown, (void)dvUnknown;
    return unsupported(c, "fmi2GetDirectionalDerivative", "providesDirectionalDerivative is false");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    (void)vr, (void)nvr, (void)order, (void)value;
    return unsupported(c, "fmi2SetRealInputDerivatives", "canInterpolateInputs is false");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    (void)vr, (void)nvr, (void)order, (void)value;
    return unsupported(c, "fmi2GetRealOutputDerivatives", "maxOutputDerivativeOrder is 0");
}

fmi2Status fmi2CancelStep(fmi2Component c)
{
    return unsupported(c, "fmi2CancelStep", "canRunAsynchronuously is false: fmi2DoStep never returns fmi2Pending");
}

/* -- stepping ------------------------------------------------------------------------------ */
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2DoStep", M(S_STEP_COMPLETE), &r);
    if (s == NULL) return r;
    r = outcome(s, "fmi2DoStep", api.doStep(s->inner, currentCommunicationPoint, communicationStepSize,
                                            noSetFMUStatePriorToCurrentPoint));
    if (r <= fmi2Warning) {
        s->last_successful_time = currentCommunicationPoint + communicationStepSize;
    } else if (r == fmi2Discard) { /* the FMU stayed at the communication point */
        s->state = S_STEP_FAILED;
        s->last_successful_time = currentCommunicationPoint;
    } /* fmi2Error: the step was refused before anything changed; the state stays stepComplete */
    return r;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Status *value)
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2GetStatus", STATUS_QUERY, &r);
    if (s == NULL) return r;
    (void)kind, (void)value;
    shim_log(s, fmi2Error, "fmi2GetStatus: no status to report (fmi2DoStep never returns fmi2Pending)");
    return fmi2Error;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Real *value)
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2GetRealStatus", STATUS_QUERY, &r);
    if (s == NULL) return r;
    if (kind != fmi2LastSuccessfulTime || value == NULL) {
        shim_log(s, fmi2Error, "fmi2GetRealStatus: only fmi2LastSuccessfulTime (%d) is available, got kind %d",
                 (int)fmi2LastSuccessfulTime, (int)kind);
        return fmi2Error;
    }
    *value = s->last_successful_time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Integer *value)
{
    (void)kind, (void)value;
    return unsupported(c, "fmi2GetIntegerStatus", "no integer status is defined for co-simulation");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Boolean *value)
{
    fmi2Status r;
    Instance *s = admit(c, "fmi2GetBooleanStatus", STATUS_QUERY, &r);
    if (s == NULL) return r;
    if (kind != fmi2Terminated || value == NULL) {
        shim_log(s, fmi2Error, "fmi2GetBooleanStatus: only fmi2Terminated (%d) is available, got kind %d",
                 (int)fmi2Terminated, (int)kind);
        return fmi2Error;
    }
    *value = fmi2False; /* the FMU never asks to end the simulation */
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind kind, fmi2String *value)
{
    (void)kind, (void)value;
    return unsupported(c, "fmi2GetStringStatus", "fmi2DoStep never returns fmi2Pending");
}
