/* Python in a native host, pythonfmu's binary and the start-up check (see fmi2_shim.c). */
#include "fmi2_shim.h"

InnerApi api;
static int api_loaded;
static pthread_mutex_t api_mutex = PTHREAD_MUTEX_INITIALIZER;

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

int ensure_python(Instance *s)
{
    if (dlsym(RTLD_DEFAULT, "Py_IsInitialized") != NULL) return 0; /* a Python host, or LD_PRELOAD */
    const char *lib = getenv("FLEXARM_FMU_LIBPYTHON");
    if (lib == NULL || *lib == '\0') lib = DEFAULT_LIBPYTHON;
    if (dlopen(lib, RTLD_NOW | RTLD_GLOBAL) != NULL) {
        shim_log(s, fmi2OK, "no Python in the host process: loaded %s", lib);
        return 0;
    }
    shim_log(s, fmi2Error,
             "fmi2Instantiate: this FMU runs Python " FLEXARM_PYTHON_VERSION " inside the host process, and none "
             "is loaded: loading %s failed (%s). Install the Python " FLEXARM_PYTHON_VERSION " shared library, or "
             "start the host with LD_PRELOAD=/path/to/" FLEXARM_LIBPYTHON " (or set FLEXARM_FMU_LIBPYTHON to its "
             "path), and set PYTHONHOME/PYTHONPATH so that numpy and scipy import; see documentation/index.html",
             lib, dlerror());
    return -1;
}

/* -- Python before pythonfmu --------------------------------------------------------- */
/* Runs with `resources` set; leaves `error` empty, or a traceback. */
/* The start-up check lives in Python (the glue's flexarm_fmu_preflight.py, in resources under this FMU build's
   private module name, see fmu_build/isolate.py); this only runs it. */
#ifndef FLEXARM_PREFLIGHT_FILE
#define FLEXARM_PREFLIGHT_FILE "flexarm_fmu_preflight.py"
#endif
static const char PREFLIGHT[] =
    "import os, runpy, traceback\n"
    "try:\n"
    "    error = runpy.run_path(os.path.join(resources, '" FLEXARM_PREFLIGHT_FILE "'))['preflight'](resources)\n"
    "except BaseException:\n"
    "    error = 'its start-up check (resources/" FLEXARM_PREFLIGHT_FILE ") failed; rebuild the FMU "
    "(python build_fmus.py --force):\\n' + traceback.format_exc(limit=-2)\n";

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
int preflight(Instance *s, const char *resources)
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
            shim_log(s, fmi2Error, "fmi2Instantiate: %s", text != NULL ? text : "(no message)");
            py.ErrClear();
        }
        py.DecRef(result);
    }
    if (path != NULL) py.DecRef(path);
    if (globals != NULL) py.DecRef(globals);
    py.GILStateRelease(gil);
    return ok ? 0 : -1;
}

int load_api(Instance *s)
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
char *resources_path(Instance *s, const char *uri)
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

void free_instance_memory(Instance *s)
{
    s->magic = 0;
    free(s->name);
    free(s);
}

