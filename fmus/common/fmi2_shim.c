/*
 * FMI 2.0 co-simulation front end of this project's FMUs (the "shim").
 *
 * build_fmus.py compiles this file once per FMU into
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
 *    pythonfmu's return value and the statuses logged during the call
 *    (warning or error): a rejected value, a refused step or a failed
 *    initialisation returns fmi2Error; fmi2Discard remains only for a step
 *    the glue discards without an error (a smaller step may succeed).
 *  - fmi2Error leaves the instance in the state it was in: our FMUs reject a
 *    value or refuse a step before changing anything, so the master may fix
 *    the value and go on (or reset, or free, as FMI 2.0 prescribes).
 *  - Argument checks pythonfmu lacks (GUID, fmuType, NULL pointers, start and
 *    stop time, FMU-state buffers with a header and checksum), the
 *    fmi2Get*Status functions, fmi2GetFMUstate into an existing state, and
 *    file URIs of any form for the resources.
 *  - Python in a native host: if no Python is loaded in the process, the shim
 *    loads libpython3.11.so.1.0 (or $FLEXARM_FMU_LIBPYTHON) with RTLD_GLOBAL
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
#define _GNU_SOURCE
#include <dlfcn.h>
#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#ifndef FLEXARM_FMU_GUID
#error "compile with -DFLEXARM_FMU_GUID=\"<guid of modelDescription.xml>\""
#endif
#ifndef FLEXARM_MODEL_IDENTIFIER
#error "compile with -DFLEXARM_MODEL_IDENTIFIER=\"<modelIdentifier>\""
#endif

#define INNER_LIBRARY "libpythonfmu-export.so"
#define DEFAULT_LIBPYTHON "libpython3.11.so.1.0"
#define INSTANCE_MAGIC 0x464c5849u /* "FLXI" */
#define STATE_MAGIC 0x464c5853u    /* "FLXS" */
#define SERIAL_MAGIC "FXS1"
#define SERIAL_HEADER 32

/* -- the FMI 2.0 co-simulation states ------------------------------------------------- */
enum { S_INSTANTIATED, S_INIT, S_STEP_COMPLETE, S_STEP_FAILED, S_TERMINATED, S_FATAL, S_COUNT };
static const char *const STATE_NAMES[S_COUNT] = {"instantiated", "initializationMode", "stepComplete",
                                                 "stepFailed", "terminated", "fatal"};
#define M(s) (1u << (s))
#define LIVE (M(S_INSTANTIATED) | M(S_INIT) | M(S_STEP_COMPLETE) | M(S_STEP_FAILED) | M(S_TERMINATED))
#define GETTABLE (M(S_INIT) | M(S_STEP_COMPLETE) | M(S_STEP_FAILED) | M(S_TERMINATED))
#define SETTABLE (M(S_INSTANTIATED) | M(S_INIT) | M(S_STEP_COMPLETE))
#define STATUS_QUERY (M(S_STEP_COMPLETE) | M(S_STEP_FAILED) | M(S_TERMINATED))

/* pythonfmu's <LogCategories> (Fmi2Slave.log_categories), the only valid debug categories. */
static const char *const CATEGORIES[] = {"logStatusWarning", "logStatusDiscard", "logStatusError",
                                         "logStatusFatal", "logAll"};
#define N_CATEGORIES (sizeof CATEGORIES / sizeof CATEGORIES[0])

/* -- pythonfmu's functions ---------------------------------------------------------- */
typedef struct {
    fmi2InstantiateTYPE *instantiate;
    fmi2FreeInstanceTYPE *freeInstance;
    fmi2SetupExperimentTYPE *setupExperiment;
    fmi2EnterInitializationModeTYPE *enterInitializationMode;
    fmi2ExitInitializationModeTYPE *exitInitializationMode;
    fmi2TerminateTYPE *terminate;
    fmi2ResetTYPE *reset;
    fmi2GetRealTYPE *getReal;
    fmi2GetIntegerTYPE *getInteger;
    fmi2GetBooleanTYPE *getBoolean;
    fmi2GetStringTYPE *getString;
    fmi2SetRealTYPE *setReal;
    fmi2SetIntegerTYPE *setInteger;
    fmi2SetBooleanTYPE *setBoolean;
    fmi2SetStringTYPE *setString;
    fmi2GetFMUstateTYPE *getFMUstate;
    fmi2SetFMUstateTYPE *setFMUstate;
    fmi2FreeFMUstateTYPE *freeFMUstate;
    fmi2SerializedFMUstateSizeTYPE *serializedFMUstateSize;
    fmi2SerializeFMUstateTYPE *serializeFMUstate;
    fmi2DeSerializeFMUstateTYPE *deSerializeFMUstate;
    fmi2DoStepTYPE *doStep;
    void (*finalizePythonInterpreter)(void); /* optional */
} InnerApi;

static InnerApi api;
static int api_loaded;
static pthread_mutex_t api_mutex = PTHREAD_MUTEX_INITIALIZER;

/* -- one instance ------------------------------------------------------------------- */
typedef struct {
    unsigned magic;
    int state;
    fmi2Component inner;
    fmi2CallbackFunctions inner_callbacks; /* given to pythonfmu, which keeps the pointer */
    fmi2CallbackLogger host_logger;
    fmi2ComponentEnvironment host_env;
    char *name;
    int logging_on;
    unsigned category_mask; /* bit i: CATEGORIES[i]; all bits: no filter */
    fmi2Status worst;       /* worst status logged by pythonfmu during the current call */
    double start_time;
    double last_successful_time;
} Instance;

/* An FMU state: pythonfmu's (a Python object) plus the shim's own. */
typedef struct {
    unsigned magic;
    int state;
    double start_time;
    double last_successful_time;
    fmi2FMUstate inner;
} State;

static Instance *as_instance(fmi2Component c)
{
    Instance *s = (Instance *)c;
    return (s != NULL && s->magic == INSTANCE_MAGIC) ? s : NULL;
}

static State *as_state(fmi2FMUstate p)
{
    State *w = (State *)p;
    return (w != NULL && w->magic == STATE_MAGIC) ? w : NULL;
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
static void emit(Instance *s, fmi2Status status, const char *category, const char *text)
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
__attribute__((format(printf, 3, 4))) static void shim_log(Instance *s, fmi2Status status, const char *fmt, ...)
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
static void inner_logger(fmi2ComponentEnvironment env, fmi2String instanceName, fmi2Status status,
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
static Instance *admit(fmi2Component c, const char *fn, unsigned allowed, fmi2Status *refusal)
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

/* Status of a forwarded call: pythonfmu's, raised by what the Python slave logged during it. */
static fmi2Status outcome(Instance *s, const char *fn, fmi2Status inner)
{
    fmi2Status r = inner;
    if (s->worst >= fmi2Error && r < fmi2Error) r = fmi2Error;
    else if (s->worst == fmi2Warning && r < fmi2Warning) r = fmi2Warning;
    if (r == fmi2Fatal && s->state != S_FATAL) {
        s->state = S_FATAL;
        shim_log(s, fmi2Fatal, "%s: pythonfmu returned fmi2Fatal; the instance cannot be used any more", fn);
    }
    return r;
}

static int null_arrays(Instance *s, const char *fn, size_t nvr, const void *vr, const void *value)
{
    if (nvr > 0 && (vr == NULL || value == NULL)) {
        shim_log(s, fmi2Error, "%s: vr[] and value[] must not be NULL when nvr = %zu; the call was ignored", fn,
                 nvr);
        return 1;
    }
    return 0;
}

/* -- loading pythonfmu's binary ----------------------------------------------------- */
/*
 * pythonfmu 0.7.0 ends with a use-after-free: at exit its static
 * std::shared_ptr<PyState> is destroyed (an exit handler) before its
 * destructor function finalizePythonInterpreter() assigns nullptr to it,
 * which frees the PyState a second time and corrupts the heap (a native host
 * then aborts in exit). Calling finalizePythonInterpreter() from an exit
 * handler registered after pythonfmu's binary was loaded runs it first,
 * while the pointer is alive; the later calls then find it empty. The shim
 * is pinned (RTLD_NODELETE) so that the handler stays mapped and runs only
 * at exit, never when a host unloads the FMU.
 */
static void finalize_python_at_exit(void) { api.finalizePythonInterpreter(); }

static int ensure_python(Instance *s)
{
    if (dlsym(RTLD_DEFAULT, "Py_IsInitialized") != NULL) return 0; /* a Python host, or LD_PRELOAD */
    const char *lib = getenv("FLEXARM_FMU_LIBPYTHON");
    if (lib == NULL || *lib == '\0') lib = DEFAULT_LIBPYTHON;
    if (dlopen(lib, RTLD_NOW | RTLD_GLOBAL) != NULL) {
        shim_log(s, fmi2OK, "no Python in the host process: loaded %s", lib);
        return 0;
    }
    shim_log(s, fmi2Error,
             "fmi2Instantiate: this FMU runs Python 3.11 inside the host process, and none is loaded: "
             "loading %s failed (%s). Install the Python 3.11 shared library, or start the host with "
             "LD_PRELOAD=/path/to/libpython3.11.so.1.0 (or set FLEXARM_FMU_LIBPYTHON to its path), and set "
             "PYTHONHOME/PYTHONPATH so that numpy and scipy import; see documentation/index.html",
             lib, dlerror());
    return -1;
}

/* -- Python before pythonfmu --------------------------------------------------------- */
/* Runs with `resources` set; leaves `error` empty, or a traceback. */
static const char PREFLIGHT[] =
    "import importlib, os, sys, traceback\n"
    "error = ''\n"
    "try:\n"
    "    provided = {e[:-3] if e.endswith('.py') else e for e in os.listdir(resources)\n"
    "                if e.endswith('.py') or os.path.isdir(os.path.join(resources, e))}\n"
    "    for name, module in list(sys.modules.items()):\n"
    "        file = getattr(module, '__file__', None)\n"
    "        if name.split('.')[0] in provided and file and not os.path.exists(file):\n"
    "            del sys.modules[name]  # from an FMU folder that is gone: this FMU's copy replaces it\n"
    "    if resources not in sys.path:\n"
    "        sys.path.insert(0, resources)\n"
    "    with open(os.path.join(resources, 'slavemodule.txt')) as f:\n"
    "        importlib.import_module(f.readline().strip())\n"
    "except BaseException:\n"
    "    error = traceback.format_exc(limit=-4)\n";

typedef struct {
    int (*IsInitialized)(void);
    void (*InitializeEx)(int);
    void *(*EvalSaveThread)(void);
    int (*GILStateEnsure)(void);
    void (*GILStateRelease)(int);
    void *(*DictNew)(void);
    int (*DictSetItemString)(void *, const char *, void *);
    void *(*DictGetItemString)(void *, const char *);
    void *(*EvalGetBuiltins)(void);
    void *(*UnicodeFromString)(const char *);
    const char *(*UnicodeAsUTF8)(void *);
    void *(*RunString)(const char *, int, void *, void *);
    void (*DecRef)(void *);
    void (*ErrClear)(void);
} PyApi;

/* Start Python if the host has not, then import the slave module; 0 if it imports. */
static int preflight(Instance *s, const char *resources)
{
    static PyApi py;
    struct { void **slot; const char *name; } table[] = {
        {(void **)&py.IsInitialized, "Py_IsInitialized"}, {(void **)&py.InitializeEx, "Py_InitializeEx"},
        {(void **)&py.EvalSaveThread, "PyEval_SaveThread"}, {(void **)&py.GILStateEnsure, "PyGILState_Ensure"},
        {(void **)&py.GILStateRelease, "PyGILState_Release"}, {(void **)&py.DictNew, "PyDict_New"},
        {(void **)&py.DictSetItemString, "PyDict_SetItemString"},
        {(void **)&py.DictGetItemString, "PyDict_GetItemString"},
        {(void **)&py.EvalGetBuiltins, "PyEval_GetBuiltins"},
        {(void **)&py.UnicodeFromString, "PyUnicode_FromString"}, {(void **)&py.UnicodeAsUTF8, "PyUnicode_AsUTF8"},
        {(void **)&py.RunString, "PyRun_String"}, {(void **)&py.DecRef, "Py_DecRef"},
        {(void **)&py.ErrClear, "PyErr_Clear"},
    };
    for (size_t i = 0; i < sizeof table / sizeof table[0]; i++) {
        if ((*table[i].slot = dlsym(RTLD_DEFAULT, table[i].name)) == NULL) {
            shim_log(s, fmi2Error, "fmi2Instantiate: the Python in this process lacks %s", table[i].name);
            return -1;
        }
    }
    if (!py.IsInitialized()) { /* as pythonfmu would, but without signal handlers; never finalised */
        /* Python ends the process if PYTHONHOME has no standard library: check the usual mistake first. */
        const char *home = getenv("PYTHONHOME");
        const char *(*version)(void) = (const char *(*)(void))dlsym(RTLD_DEFAULT, "Py_GetVersion");
        int major = 0, minor = 0;
        if (home != NULL && *home != '\0' && version != NULL && sscanf(version(), "%d.%d", &major, &minor) == 2) {
            char encodings[4096];
            snprintf(encodings, sizeof encodings, "%.*s/lib/python%d.%d/encodings/__init__.py",
                     (int)strcspn(home, ":"), home, major, minor);
            FILE *f = fopen(encodings, "r");
            if (f == NULL) {
                shim_log(s, fmi2Error, "fmi2Instantiate: PYTHONHOME=%s is not the prefix of a Python %d.%d (no %s); "
                         "starting Python would end the process", home, major, minor, encodings);
                return -1;
            }
            fclose(f);
        }
        py.InitializeEx(0);
        py.EvalSaveThread(); /* release the GIL: every call takes it with PyGILState_Ensure */
        shim_log(s, fmi2OK, "started the Python interpreter");
    }
    int gil = py.GILStateEnsure();
    int ok = 0;
    void *globals = py.DictNew(), *path = py.UnicodeFromString(resources), *result = NULL;
    if (globals != NULL && path != NULL && py.DictSetItemString(globals, "__builtins__", py.EvalGetBuiltins()) == 0 &&
        py.DictSetItemString(globals, "resources", path) == 0)
        result = py.RunString(PREFLIGHT, 257 /* Py_file_input */, globals, globals);
    if (result == NULL) {
        py.ErrClear();
        shim_log(s, fmi2Error, "fmi2Instantiate: could not run Python code to load the FMU");
    } else {
        void *error = py.DictGetItemString(globals, "error"); /* borrowed */
        const char *text = error != NULL ? py.UnicodeAsUTF8(error) : NULL;
        if (text != NULL && *text == '\0') {
            ok = 1;
        } else {
            shim_log(s, fmi2Error, "fmi2Instantiate: the FMU's Python code cannot be loaded (NumPy and SciPy must "
                     "be importable: PYTHONPATH):\n%s", text != NULL ? text : "(no message)");
            py.ErrClear();
        }
        py.DecRef(result);
    }
    if (path != NULL) py.DecRef(path);
    if (globals != NULL) py.DecRef(globals);
    py.GILStateRelease(gil);
    return ok ? 0 : -1;
}

static int load_api(Instance *s)
{
    pthread_mutex_lock(&api_mutex);
    int ok = api_loaded;
    if (!ok && ensure_python(s) == 0) {
        Dl_info info;
        char path[4096];
        if (dladdr((void *)&fmi2Instantiate, &info) == 0 || info.dli_fname == NULL) {
            shim_log(s, fmi2Error, "fmi2Instantiate: cannot find the folder of this FMU's binary");
            goto done;
        }
        snprintf(path, sizeof path, "%s", info.dli_fname);
        char *slash = strrchr(path, '/');
        size_t dir_len = slash ? (size_t)(slash - path) + 1 : 0;
        snprintf(path + dir_len, sizeof path - dir_len, "%s", INNER_LIBRARY);
        void *h = dlopen(path, RTLD_NOW | RTLD_LOCAL);
        if (h == NULL) {
            shim_log(s, fmi2Error, "fmi2Instantiate: cannot load pythonfmu's binary %s: %s", path, dlerror());
            goto done;
        }
        struct { void **slot; const char *name; } table[] = {
            {(void **)&api.instantiate, "fmi2Instantiate"},
            {(void **)&api.freeInstance, "fmi2FreeInstance"},
            {(void **)&api.setupExperiment, "fmi2SetupExperiment"},
            {(void **)&api.enterInitializationMode, "fmi2EnterInitializationMode"},
            {(void **)&api.exitInitializationMode, "fmi2ExitInitializationMode"},
            {(void **)&api.terminate, "fmi2Terminate"},
            {(void **)&api.reset, "fmi2Reset"},
            {(void **)&api.getReal, "fmi2GetReal"},
            {(void **)&api.getInteger, "fmi2GetInteger"},
            {(void **)&api.getBoolean, "fmi2GetBoolean"},
            {(void **)&api.getString, "fmi2GetString"},
            {(void **)&api.setReal, "fmi2SetReal"},
            {(void **)&api.setInteger, "fmi2SetInteger"},
            {(void **)&api.setBoolean, "fmi2SetBoolean"},
            {(void **)&api.setString, "fmi2SetString"},
            {(void **)&api.getFMUstate, "fmi2GetFMUstate"},
            {(void **)&api.setFMUstate, "fmi2SetFMUstate"},
            {(void **)&api.freeFMUstate, "fmi2FreeFMUstate"},
            {(void **)&api.serializedFMUstateSize, "fmi2SerializedFMUstateSize"},
            {(void **)&api.serializeFMUstate, "fmi2SerializeFMUstate"},
            {(void **)&api.deSerializeFMUstate, "fmi2DeSerializeFMUstate"},
            {(void **)&api.doStep, "fmi2DoStep"},
        };
        for (size_t i = 0; i < sizeof table / sizeof table[0]; i++) {
            *table[i].slot = dlsym(h, table[i].name);
            if (*table[i].slot == NULL) {
                shim_log(s, fmi2Error, "fmi2Instantiate: %s lacks %s", path, table[i].name);
                goto done;
            }
        }
        *(void **)&api.finalizePythonInterpreter = dlsym(h, "finalizePythonInterpreter");
        if (api.finalizePythonInterpreter != NULL &&
            dlopen(info.dli_fname, RTLD_LAZY | RTLD_NOLOAD | RTLD_NODELETE) != NULL)
            atexit(finalize_python_at_exit);
        api_loaded = ok = 1; /* pythonfmu's binary stays loaded: it owns the interpreter it may have started */
    }
done:
    pthread_mutex_unlock(&api_mutex);
    return ok ? 0 : -1;
}

/* Folder of the resources from an FMI "file:" URI (any of file:/p, file:///p, file://localhost/p), or
   from this binary's location if the host gives none. Returns a malloc'ed path or NULL. */
static char *resources_path(Instance *s, const char *uri)
{
    if (uri == NULL || *uri == '\0') {
        Dl_info info;
        if (dladdr((void *)&fmi2Instantiate, &info) == 0 || info.dli_fname == NULL) return NULL;
        char *p = malloc(strlen(info.dli_fname) + 16);
        if (p == NULL) return NULL;
        strcpy(p, info.dli_fname); /* <fmu>/binaries/linux64/<id>.so -> <fmu>/resources */
        for (int up = 0; up < 3; up++) {
            char *slash = strrchr(p, '/');
            if (slash == NULL) { free(p); return NULL; }
            *slash = '\0';
        }
        strcat(p, "/resources");
        shim_log(s, fmi2OK, "no fmuResourceLocation given: using %s", p);
        return p;
    }
    const char *p = uri;
    if (strncmp(p, "file:", 5) == 0) {
        p += 5;
        if (strncmp(p, "//", 2) == 0) {
            p += 2;
            if (strncmp(p, "localhost/", 10) == 0) p += 9;
            else if (*p != '/') return NULL; /* another host */
        }
    }
    char *out = malloc(strlen(p) + 1), *o = out;
    if (out == NULL) return NULL;
    for (; *p; p++) {
        unsigned hi, lo;
        if (p[0] == '%' && p[1] && p[2] && sscanf(p + 1, "%1x%1x", &hi, &lo) == 2) {
            *o++ = (char)(hi * 16 + lo);
            p += 2;
        } else {
            *o++ = *p;
        }
    }
    *o = '\0';
    return out;
}

/*
 * pythonfmu 0.7.0 delivers the Python slave's queued log messages at the end of every call, except after
 * creating the slave object (fmi2Instantiate, fmi2Reset): what the slave's __init__ logs stays queued. Its
 * fmi2FreeInstance deletes its logger object before the slave (C++ member order in Fmi2Component), and the
 * slave's destructor then delivers the queue through the deleted logger: a use-after-free that crashed hosts
 * freeing an instance they never initialised (a master whose wiring fails), depending on what had reused the
 * memory. An empty fmi2GetReal right after the slave object is made delivers the queue while the logger is
 * alive, in the call that caused it; the queue is then empty whenever pythonfmu's destructor runs.
 */
static fmi2Status deliver_queued_log(Instance *s)
{
    fmi2ValueReference vr = 0;
    fmi2Real value = 0.0;
    return api.getReal(s->inner, &vr, 0, &value); /* the slave's get_real([]): no effect in instantiated mode */
}

static void free_instance_memory(Instance *s)
{
    s->magic = 0;
    free(s->name);
    free(s);
}

/* =========================================================================================
 * FMI 2.0 functions
 * ========================================================================================= */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

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
    return s;
fail:
    free_instance_memory(s);
    return NULL;
}

void fmi2FreeInstance(fmi2Component c)
{
    Instance *s = as_instance(c);
    if (s == NULL) return;
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
    } else if ((w = calloc(1, sizeof *w)) == NULL) {
        api.freeFMUstate(s->inner, &inner);
        shim_log(s, fmi2Error, "fmi2GetFMUstate: out of memory");
        return fmi2Error;
    }
    w->magic = STATE_MAGIC;
    w->inner = inner;
    w->state = s->state;
    w->start_time = s->start_time;
    w->last_successful_time = s->last_successful_time;
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
        shim_log(s, fmi2Error, "fmi2SetFMUstate: not a state of this FMU (NULL, freed or foreign)");
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
    r = outcome(s, "fmi2FreeFMUstate", api.freeFMUstate(s->inner, &w->inner));
    w->magic = 0;
    free(w);
    *FMUstate = NULL;
    return r;
}

/* Serialized state: "FXS1", uint32 state, double start time, double last successful time,
   uint64 FNV-1a hash of the payload, then pythonfmu's payload (JSON). */
static uint64_t fnv1a(const fmi2Byte *p, size_t n)
{
    uint64_t h = 1469598103934665603ull;
    for (size_t i = 0; i < n; i++) h = (h ^ (unsigned char)p[i]) * 1099511628211ull;
    return h;
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
    uint64_t hash = fnv1a(serializedState + SERIAL_HEADER, n);
    memcpy(serializedState, SERIAL_MAGIC, 4);
    memcpy(serializedState + 4, &st, 4);
    memcpy(serializedState + 8, &w->start_time, 8);
    memcpy(serializedState + 16, &w->last_successful_time, 8);
    memcpy(serializedState + 24, &hash, 8);
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
        st >= (uint32_t)S_FATAL || hash != fnv1a(serializedState + SERIAL_HEADER, size - SERIAL_HEADER)) {
        shim_log(s, fmi2Error, "fmi2DeSerializeFMUstate: the %zu bytes are not a state serialized by %s "
                 "(wrong header, size or checksum); nothing changed", size, FLEXARM_MODEL_IDENTIFIER);
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
    } else if ((w = calloc(1, sizeof *w)) == NULL) {
        api.freeFMUstate(s->inner, &inner);
        shim_log(s, fmi2Error, "fmi2DeSerializeFMUstate: out of memory");
        return fmi2Error;
    }
    w->magic = STATE_MAGIC;
    w->inner = inner;
    w->state = (int)st;
    memcpy(&w->start_time, serializedState + 8, 8);
    memcpy(&w->last_successful_time, serializedState + 16, 8);
    *FMUstate = w;
    return r;
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
