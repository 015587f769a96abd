/*
 * FMI 2.0 co-simulation glue shared by every native FMU of flexarm-fmi.
 *
 * The glue owns the FMI side: the state machine (a table of the states in which
 * each call is allowed, as in the Modelica Reference-FMUs), value storage with
 * type, range and causality checks, logging, resource loading with SHA-256
 * checks, FMU state copies and (de)serialisation. A model supplies a table of
 * its variables (generated from the Python FMU's modelDescription.xml) and the
 * callbacks of ModelInfo; it never sees an FMI call directly.
 *
 * Values live in one double per variable (Integer, Enumeration and Boolean as
 * whole numbers), indexed by the variable's position in the table. No FMU has
 * a String variable: a file a model may read (a learned correction) lies in
 * its resources folder (glue_resource_file).
 */
#ifndef FLEXARM_FMI2_GLUE_H
#define FLEXARM_FMI2_GLUE_H

#include <stddef.h>

#include "fmi2Functions.h"
#include "libm_link.h" /* libm's functions through libm_link.c: the sources build and load without libm */

typedef enum { VT_REAL, VT_INTEGER, VT_BOOLEAN, VT_ENUMERATION } VarType;
typedef enum { CA_PARAMETER, CA_INPUT, CA_OUTPUT } Causality;

typedef struct {
    const char *name;
    fmi2ValueReference vr;
    VarType type;
    Causality causality;
    double start, min, max; /* min/max: -/+HUGE_VAL where unbounded */
    const char *unit;       /* "" when none */
} VarInfo;

typedef struct {
    const char *file;   /* name inside resources/ */
    const char *sha256; /* recorded at build time, lower-case hex */
} ResourceInfo;

struct Instance;

typedef struct {
    const char *model_identifier;
    const char *guid;
    const VarInfo *vars;
    size_t n_vars;
    const ResourceInfo *resources;
    size_t n_resources;
    size_t state_size; /* bytes of the model's dynamic state (flat: no pointers), copied by get/set FMU state */
    /* Parse the resource files (already SHA-256 checked) into inst->data; 0 on success (after logging why not). */
    int (*load)(struct Instance *inst, char *const *contents, const size_t *sizes);
    void (*unload)(struct Instance *inst);
    /* From the parameters and inputs: set the state at the start time and the outputs. fmi2Error names the
       parameter (the FMU stays in initialisation mode). Called for reads in initialisation mode and at exit. */
    fmi2Status (*initialize)(struct Instance *inst);
    /* Sampled models: the outputs of the current sample, a pure function of the committed state and the inputs
       present (it must not change the committed state: reads, any number of them, change nothing). Called
       before a read when inputs changed, and by fmi2DoStep before do_step. NULL: outputs change only in do_step. */
    fmi2Status (*sample)(struct Instance *inst);
    /* Advance from t to t + h (inputs held: those present at fmi2DoStep); the outputs at t + h. Must leave the
       state unchanged on error. Sampled models count whole samples with glue_whole_samples. */
    fmi2Status (*do_step)(struct Instance *inst, double t, double h);
    /* Resources read when first needed (glue_read_resource), NULL-terminated; load gets NULL for them. NULL: every
       resource is read and checked at fmi2Instantiate. (A resource a run never needs is neither read nor hashed:
       the paper's law reads the predictor's designs only when it measures a loop delay.) */
    const char *const *on_demand;
} ModelInfo;

typedef struct Instance {
    unsigned magic;
    int fmi_state;
    char *name;
    fmi2CallbackLogger logger;
    fmi2ComponentEnvironment env;
    int logging_on;
    double time;
    double *values;         /* one per variable */
    unsigned char *invalid; /* 1 while a rejected value is pending for an input (doStep refuses) */
    int outputs_stale;      /* feedthrough: inputs changed since the last sample */
    int outputs_read;       /* an output was read since initialisation began (a master that exchanges values) */
    void *state;            /* model state, ModelInfo.state_size bytes */
    void *data;             /* model constants from the resources (not part of the FMU state) */
    double *starts;         /* start values: the table's, or a case's (glue_load_start_values) */
    char *resource_dir;     /* the resources folder's local path (NULL: the URI was no file:// URI) */
} Instance;

extern const ModelInfo MODEL_INFO;

/* Log a message (printf format) as the instance; errors always reach the host, OK only with logging on. */
void glue_log(const Instance *inst, fmi2Status status, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;

/* The local path of the file `name` in the FMU's resources folder (malloc'ed), NULL without a folder. */
char *glue_resource_file(const Instance *inst, const char *name);

/* The local path of a file:// resources URI (malloc'ed), NULL for anything else. */
char *glue_resource_dir(const char *uri);

/* Value of variable `index` (position in MODEL_INFO.vars). */
#define VALUE(inst, index) ((inst)->values[(index)])

/* Parse whitespace-separated 16-digit hex IEEE-754 doubles after the label `name` in a resource text.
   Returns 0 and fills out[0..n-1], or -1 after logging what is wrong. */
int glue_read_doubles(const Instance *inst, const char *file, const char *text, const char *name, double *out,
                      size_t n);

/* The resource `file` of MODEL_INFO, read whole from the resources folder and checked against the SHA-256 recorded at
   build time, NUL-terminated (*size bytes before the NUL); NULL after logging why, naming the FMI call `when`. The
   caller frees it. */
char *glue_read_resource(const Instance *inst, const char *file, const char *when, size_t *size);

/* The whole file at `path`, NUL-terminated, in a malloc'ed buffer (*size bytes before the NUL); NULL if it
   cannot be read. The caller frees it. */
char *glue_read_file(const char *path, size_t *size);

/* The longest communication step these FMUs take, s: a longer one is refused with fmi2Error naming step_size, so
   a step returns in bounded time. The same bound as the Python FMUs' MAX_STEP_SIZE (fmus/common/flexarm_fmu_base.py,
   where the reason is written; a test checks that the two agree). */
#define GLUE_MAX_STEP_SIZE 10.0

/* A step within this many seconds of a whole number of samples counts as that number. */
#define GLUE_STEP_TOLERANCE 1e-9

/* The number *n >= 0 of samples of `period` s in a communication step h s: 0 if |h - n period| <= 1e-9 s, else -1
   (the caller refuses the step naming step_size). n = 0 (a step of at most 1e-9 s, e.g. a last step shortened
   by rounding) means no sample instant lies in the step: a sampled model does nothing. */
int glue_whole_samples(double h, double period, double *n);

/* Read and check every resource of MODEL_INFO but those read on demand, then MODEL_INFO.load; 0 on success (after
   logging why not). */
int glue_load_resources(Instance *inst, const char *uri);

/* A case's start values, if resources/flexarm_start_values.txt exists (written by the SSP export of
   flexarm-fmi's scenarios, so a master that applies no parameter set still runs the case): into inst->starts.
   0 on success or without the file; -1 (after logging which line) on a name that is no parameter or a value
   outside its range. */
int glue_load_start_values(Instance *inst, const char *uri);

#endif
