/*
 * Shared declarations of the FMUs' C front end (the "shim"), compiled from three files together:
 *   fmi2_shim.c         the FMI 2.0 state machine, logging and the FMI functions;
 *   fmi2_shim_python.c  Python in a native host, loading pythonfmu's binary, the start-up check;
 *   fmi2_shim_state.c   FMU states (get/set/free) and their serialisation.
 * See fmi2_shim.c for what the front end does and why.
 */
#ifndef FLEXARM_FMI2_SHIM_H
#define FLEXARM_FMI2_SHIM_H
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
#include "live_table.h" /* fmus/native/common: shared with the native FMUs */

#ifndef FLEXARM_FMU_GUID
#error "compile with -DFLEXARM_FMU_GUID=\"<guid of modelDescription.xml>\""
#endif
#ifndef FLEXARM_MODEL_IDENTIFIER
#error "compile with -DFLEXARM_MODEL_IDENTIFIER=\"<modelIdentifier>\""
#endif

#define INNER_LIBRARY "libpythonfmu-export.so"
#ifndef FLEXARM_LIBPYTHON /* the building Python's sysconfig INSTSONAME, passed by fmu_build.compile */
#error "compile with -DFLEXARM_LIBPYTHON=\"<file name of the Python shared library>\""
#endif
#ifndef FLEXARM_PYTHON_VERSION
#error "compile with -DFLEXARM_PYTHON_VERSION=\"<major.minor>\""
#endif
#define DEFAULT_LIBPYTHON FLEXARM_LIBPYTHON
#define INSTANCE_MAGIC 0x464c5849u /* "FLXI" */
#define STATE_MAGIC 0x464c5853u    /* "FLXS" */
#define SERIAL_MAGIC "FXS1"
#define SERIAL_HEADER 32

/* -- the FMI 2.0 co-simulation states ------------------------------------------------- */
enum { S_INSTANTIATED, S_INIT, S_STEP_COMPLETE, S_STEP_FAILED, S_TERMINATED, S_FATAL, S_COUNT };
extern const char *const STATE_NAMES[S_COUNT];
#define M(s) (1u << (s))
#define LIVE (M(S_INSTANTIATED) | M(S_INIT) | M(S_STEP_COMPLETE) | M(S_STEP_FAILED) | M(S_TERMINATED))
#define GETTABLE (M(S_INIT) | M(S_STEP_COMPLETE) | M(S_STEP_FAILED) | M(S_TERMINATED))
#define SETTABLE (M(S_INSTANTIATED) | M(S_INIT) | M(S_STEP_COMPLETE))
#define STATUS_QUERY (M(S_STEP_COMPLETE) | M(S_STEP_FAILED) | M(S_TERMINATED))

/* pythonfmu's <LogCategories> (Fmi2Slave.log_categories), the only valid debug categories. */
#define N_CATEGORIES 5
extern const char *const CATEGORIES[N_CATEGORIES];

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

extern InnerApi api;

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

/* An FMU state: pythonfmu's (a Python object) plus the shim's own, sealed by a checksum of the fields before it
   (a host that scribbles on it is refused, not followed to a wild pointer). */
typedef struct {
    unsigned magic;
    int state;
    double start_time;
    double last_successful_time;
    fmi2FMUstate inner;
    uint64_t seal;
} State;
/* tests/test_python_state_fuzz.py flips every bit of these 40 bytes */
_Static_assert(sizeof(State) == 40, "State layout changed: update tests/test_python_state_fuzz.py");

/* -- shared between the front end's files ---------------------------------------------- */
/* The live instances and states of this binary (live_table.h): a handle is read only once found here, so a
   second fmi2FreeInstance, a freed state or another FMU's state is refused without touching its memory. */
extern LiveTable shim_instances, shim_states;
/* fmi2_shim.c: instances, logging, the state machine */
Instance *as_instance(fmi2Component c);
void emit(Instance *s, fmi2Status status, const char *category, const char *text);
__attribute__((format(printf, 3, 4))) void shim_log(Instance *s, fmi2Status status, const char *fmt, ...);
void inner_logger(fmi2ComponentEnvironment env, fmi2String instanceName, fmi2Status status, fmi2String category,
                  fmi2String message, ...);
Instance *admit(fmi2Component c, const char *fn, unsigned allowed, fmi2Status *refusal);
fmi2Status outcome(Instance *s, const char *fn, fmi2Status inner);
int null_arrays(Instance *s, const char *fn, size_t nvr, const void *vr, const void *value);
/* fmi2_shim_python.c: Python in the host, pythonfmu's binary, the start-up check */
int load_api(Instance *s);
int preflight(Instance *s, const char *resources);
char *resources_path(Instance *s, const char *uri);
void free_instance_memory(Instance *s);
/* fmi2_shim_state.c: FMU states and their serialisation */
State *as_state(fmi2FMUstate p);

#endif /* FLEXARM_FMI2_SHIM_H */
