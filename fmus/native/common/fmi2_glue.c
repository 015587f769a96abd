/*
 * FMI 2.0 co-simulation glue of the native FMUs (see fmi2_glue.h).
 *
 * Behaviour, as the Python FMUs' (docs/fmu-interface.md, "Errors"): a call not
 * allowed in the current state, a value out of range or not finite, a fixed
 * parameter set after initialisation or an output set returns fmi2Error with a
 * message and changes nothing; a call with one bad value applies none of its
 * values, and the rejected variable blocks fmi2ExitInitializationMode
 * (parameters) or fmi2DoStep (inputs) until a valid value is set.
 */
#include "fmi2_glue_internal.h"

#include <math.h>
#include <stddef.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>


#define INSTANCE_MAGIC 0x464e5849u /* "FNXI" */

/* -- the state machine: for each call, the states in which it is allowed ------------------ */
static const char *const STATE_NAMES[S_COUNT] = {"instantiated", "initializationMode", "stepComplete",
                                                 "stepFailed", "terminated"};
#define B(s) (1u << (s))
#define ANY (B(S_INSTANTIATED) | B(S_INIT) | B(S_STEP_COMPLETE) | B(S_STEP_FAILED) | B(S_TERMINATED))


static const struct {
    const char *name;
    unsigned allowed;
} CALLS[F_COUNT] = {
    [F_SET_DEBUG_LOGGING] = {"fmi2SetDebugLogging", ANY},
    [F_SETUP_EXPERIMENT] = {"fmi2SetupExperiment", B(S_INSTANTIATED)},
    [F_ENTER_INIT] = {"fmi2EnterInitializationMode", B(S_INSTANTIATED)},
    [F_EXIT_INIT] = {"fmi2ExitInitializationMode", B(S_INIT)},
    [F_TERMINATE] = {"fmi2Terminate", B(S_STEP_COMPLETE) | B(S_STEP_FAILED)},
    [F_RESET] = {"fmi2Reset", ANY},
    [F_GET] = {"fmi2Get*", B(S_INIT) | B(S_STEP_COMPLETE) | B(S_STEP_FAILED) | B(S_TERMINATED)},
    [F_SET] = {"fmi2Set*", B(S_INSTANTIATED) | B(S_INIT) | B(S_STEP_COMPLETE)},
    [F_GET_STATE] = {"fmi2GetFMUstate", ANY},
    [F_SET_STATE] = {"fmi2SetFMUstate", ANY},
    [F_SERIALIZE] = {"fmi2(De)SerializeFMUstate", ANY},
    [F_DO_STEP] = {"fmi2DoStep", B(S_STEP_COMPLETE)},
    [F_STATUS] = {"fmi2Get*Status", B(S_STEP_COMPLETE) | B(S_STEP_FAILED) | B(S_TERMINATED)},
};

/* -- logging ----------------------------------------------------------------------------- */
static const char *category_of(fmi2Status status)
{
    switch (status) {
    case fmi2Warning: return "logStatusWarning";
    case fmi2Discard: return "logStatusDiscard";
    case fmi2Error: return "logStatusError";
    case fmi2Fatal: return "logStatusFatal";
    default: return "logAll";
    }
}

void glue_log(const Instance *inst, fmi2Status status, const char *fmt, ...)
{
    if (inst == NULL || inst->logger == NULL || (status == fmi2OK && !inst->logging_on)) return;
    char body[2048], escaped[4200];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(body, sizeof body, fmt, ap);
    va_end(ap);
    char *o = escaped; /* the host's logger takes a printf format: double every '%' */
    for (const char *p = body; *p && o < escaped + sizeof escaped - 2; p++) {
        *o++ = *p;
        if (*p == '%') *o++ = '%';
    }
    *o = '\0';
    inst->logger(inst->env, inst->name, status, category_of(status), escaped);
}

/* -- live instances and FMU states (live_table.h) ------------------------------------------------ */
static LiveTable live_instances;
LiveTable glue_live_states;

static Instance *as_instance(fmi2Component c)
{
    if (c == NULL || !live_contains(&live_instances, c)) return NULL;
    Instance *inst = (Instance *)c;
    return inst->magic == INSTANCE_MAGIC ? inst : NULL;
}

/* The instance if `call` is allowed in its state; otherwise log why (naming `fn`, or the call's name) and return
   NULL. */
static Instance *admit_as(fmi2Component c, Call call, const char *fn)
{
    Instance *inst = as_instance(c);
    if (inst == NULL) return NULL;
    if (CALLS[call].allowed & B(inst->fmi_state)) return inst;
    char list[256] = "";
    for (int s = 0; s < S_COUNT; s++)
        if (CALLS[call].allowed & B(s)) {
            if (list[0]) strcat(list, ", ");
            strcat(list, STATE_NAMES[s]);
        }
    glue_log(inst, fmi2Error, "%s is not allowed in state '%s' (allowed in: %s); the call was ignored",
             fn != NULL ? fn : CALLS[call].name, STATE_NAMES[inst->fmi_state], list);
    return NULL;
}

Instance *glue_admit(fmi2Component c, Call call) { return admit_as(c, call, NULL); }

/* -- variables ----------------------------------------------------------------------------- */
static long find_var(fmi2ValueReference vr)
{
    if (vr < MODEL_INFO.n_vars && MODEL_INFO.vars[vr].vr == vr) return (long)vr; /* the usual numbering: no search */
    for (size_t i = 0; i < MODEL_INFO.n_vars; i++)
        if (MODEL_INFO.vars[i].vr == vr) return (long)i;
    return -1;
}

static const char *type_name(VarType t)
{
    static const char *const names[] = {"Real", "Integer", "Boolean", "Enumeration"};
    return names[t];
}

static void range_text(const VarInfo *v, char *buf, size_t size)
{
    if (v->type == VT_BOOLEAN) snprintf(buf, size, "true or false");
    else if (isinf(v->min) && isinf(v->max)) snprintf(buf, size, "any finite value");
    else if (isinf(v->max)) snprintf(buf, size, "[%.17g, inf)", v->min);
    else if (isinf(v->min)) snprintf(buf, size, "(-inf, %.17g]", v->max);
    else snprintf(buf, size, "[%.17g, %.17g]", v->min, v->max);
}

static void reset_values(Instance *inst)
{
    memcpy(inst->values, inst->starts, MODEL_INFO.n_vars * sizeof *inst->values);
    memset(inst->invalid, 0, MODEL_INFO.n_vars);
    memset(inst->state, 0, MODEL_INFO.state_size ? MODEL_INFO.state_size : 1);
    inst->time = 0.0;
    inst->outputs_stale = 1;
    inst->outputs_read = 0;
}

/* Check one value for variable i; 0 if it may be applied (logs the error otherwise). */
static int check_value(Instance *inst, long i, fmi2ValueReference vr, VarType given, double x)
{
    if (i < 0) {
        glue_log(inst, fmi2Error, "value reference %u: no such variable", (unsigned)vr);
        return -1;
    }
    const VarInfo *v = &MODEL_INFO.vars[i];
    char range[96] = ""; /* formatted only for a message (a set per step must not pay for snprintf) */
    VarType expect = v->type == VT_ENUMERATION ? VT_INTEGER : v->type;
    if (expect != given) {
        glue_log(inst, fmi2Error, "%s: is a %s variable, not %s (set it with fmi2Set%s)", v->name, type_name(v->type),
                 type_name(given), type_name(expect));
        return -1;
    }
    if (v->causality == CA_OUTPUT) {
        glue_log(inst, fmi2Error, "%s: is an output, it cannot be set", v->name);
        return -1;
    }
    if (v->causality == CA_PARAMETER && inst->fmi_state > S_INIT) {
        range_text(v, range, sizeof range);
        glue_log(inst, fmi2Error, "%s: a fixed parameter can be set only before fmi2ExitInitializationMode "
                 "(allowed range %s)", v->name, range);
        return -1;
    }
    if (!isfinite(x) || x < v->min || x > v->max) {
        range_text(v, range, sizeof range);
        glue_log(inst, fmi2Error, "%s = %.17g%s%s: %s the allowed range %s", v->name, x, v->unit[0] ? " " : "",
                 v->unit, isfinite(x) ? "outside" : "not a finite value in", range);
        if (given == VT_REAL || given == VT_INTEGER) inst->invalid[i] = 1;
        return -1;
    }
    return 0;
}

static fmi2Status set_values(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, VarType type,
                             const double *x)
{
    static const char *const fn_name[] = {"fmi2SetReal", "fmi2SetInteger", "fmi2SetBoolean", "fmi2SetInteger"};
    Instance *inst = admit_as(c, F_SET, fn_name[type]);
    if (inst == NULL) return fmi2Error;
    if (nvr > 0 && (vr == NULL || x == NULL)) {
        glue_log(inst, fmi2Error, "fmi2Set%s: vr[] and value[] must not be NULL", type_name(type));
        return fmi2Error;
    }
    int bad = 0;
    for (size_t k = 0; k < nvr; k++) bad |= check_value(inst, find_var(vr[k]), vr[k], type, x[k]) != 0;
    if (bad) return fmi2Error; /* none applied */
    for (size_t k = 0; k < nvr; k++) {
        long i = find_var(vr[k]);
        if (inst->values[i] != x[k]) inst->outputs_stale = 1;
        inst->values[i] = x[k];
        inst->invalid[i] = 0;
    }
    if (inst->fmi_state <= S_INIT && nvr > 0) inst->outputs_stale = 1;
    return fmi2OK;
}

/* Bring the outputs up to date before a read. */
static fmi2Status refresh_outputs(Instance *inst)
{
    if (!inst->outputs_stale) return fmi2OK;
    fmi2Status s = fmi2OK;
    if (inst->fmi_state == S_INIT) s = MODEL_INFO.initialize(inst);
    else if (inst->fmi_state == S_STEP_COMPLETE && MODEL_INFO.sample != NULL) s = MODEL_INFO.sample(inst);
    if (s == fmi2OK) inst->outputs_stale = 0;
    return s;
}

static fmi2Status get_values(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, VarType type, double *x)
{
    static const char *const fn_name[] = {"fmi2GetReal", "fmi2GetInteger", "fmi2GetBoolean", "fmi2GetInteger"};
    Instance *inst = admit_as(c, F_GET, fn_name[type]);
    if (inst == NULL) return fmi2Error;
    if (nvr > 0 && (vr == NULL || x == NULL)) {
        glue_log(inst, fmi2Error, "fmi2Get%s: vr[] and value[] must not be NULL", type_name(type));
        return fmi2Error;
    }
    int needs_outputs = 0;
    for (size_t k = 0; k < nvr; k++) {
        long i = find_var(vr[k]);
        if (i < 0) {
            glue_log(inst, fmi2Error, "value reference %u: no such variable", (unsigned)vr[k]);
            return fmi2Error;
        }
        VarType t = MODEL_INFO.vars[i].type == VT_ENUMERATION ? VT_INTEGER : MODEL_INFO.vars[i].type;
        if (t != type) {
            glue_log(inst, fmi2Error, "%s: is a %s variable, not %s", MODEL_INFO.vars[i].name,
                     type_name(MODEL_INFO.vars[i].type), type_name(type));
            return fmi2Error;
        }
        needs_outputs |= MODEL_INFO.vars[i].causality == CA_OUTPUT;
    }
    if (needs_outputs) {
        fmi2Status s = refresh_outputs(inst);
        if (s > fmi2Warning) return s;
        inst->outputs_read = 1;
    }
    for (size_t k = 0; k < nvr; k++) x[k] = inst->values[find_var(vr[k])];
    return fmi2OK;
}

/* -- FMI functions ------------------------------------------------------------------------ */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    (void)visible;
    Instance *inst = calloc(1, sizeof *inst);
    if (inst == NULL) return NULL;
    inst->magic = INSTANCE_MAGIC;
    inst->name = malloc(strlen(instanceName ? instanceName : "") + 1);
    strcpy(inst->name, instanceName ? instanceName : "");
    inst->logger = functions ? functions->logger : NULL;
    inst->env = functions ? functions->componentEnvironment : NULL;
    inst->logging_on = loggingOn;
    inst->values = calloc(MODEL_INFO.n_vars, sizeof *inst->values);
    inst->invalid = calloc(MODEL_INFO.n_vars, 1);
    inst->state = calloc(1, MODEL_INFO.state_size ? MODEL_INFO.state_size : 1);
    inst->starts = calloc(MODEL_INFO.n_vars, sizeof *inst->starts);
    inst->resource_dir = glue_resource_dir(fmuResourceLocation);
    int ok = inst->values && inst->invalid && inst->state && inst->starts;
    for (size_t i = 0; ok && i < MODEL_INFO.n_vars; i++) inst->starts[i] = MODEL_INFO.vars[i].start;
    if (ok && fmuType != fmi2CoSimulation) {
        glue_log(inst, fmi2Error, "fmi2Instantiate: %s is a co-simulation FMU only (fmuType must be "
                 "fmi2CoSimulation)", MODEL_INFO.model_identifier);
        ok = 0;
    }
    if (ok && (fmuGUID == NULL || strcmp(fmuGUID, MODEL_INFO.guid) != 0)) {
        glue_log(inst, fmi2Error, "fmi2Instantiate: fmuGUID %s does not match this binary's %s (modelDescription.xml "
                 "and binary are from different builds)", fmuGUID ? fmuGUID : "(null)", MODEL_INFO.guid);
        ok = 0;
    }
    if (ok && glue_load_resources(inst, fmuResourceLocation) != 0) ok = 0;
    if (ok && glue_load_start_values(inst, fmuResourceLocation) != 0) ok = 0;
    if (ok && live_add(&live_instances, inst, NULL) != 0) {
        glue_log(inst, fmi2Error, "fmi2Instantiate: out of memory");
        ok = 0;
    }
    if (!ok) {
        free(inst->values), free(inst->invalid), free(inst->state), free(inst->starts), free(inst->name);
        free(inst->resource_dir);
        inst->magic = 0;
        free(inst);
        return NULL;
    }
    reset_values(inst);
    inst->fmi_state = S_INSTANTIATED;
    return inst;
}

/* A second call with the same pointer (or any pointer that is no live instance of this FMU) does nothing: the
   pointer is looked up, never read. States the instance made and the host did not free are freed with it. */
void fmi2FreeInstance(fmi2Component c)
{
    if (c == NULL || !live_remove(&live_instances, c)) return;
    Instance *inst = (Instance *)c;
    for (void *snap; (snap = live_take_owned(&glue_live_states, inst)) != NULL;) glue_free_snapshot(snap);
    if (MODEL_INFO.unload != NULL) MODEL_INFO.unload(inst);
    inst->magic = 0;
    free(inst->values), free(inst->invalid), free(inst->state), free(inst->starts), free(inst->name);
    free(inst->resource_dir);
    free(inst);
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[])
{
    static const char *const known[] = {"logStatusWarning", "logStatusDiscard", "logStatusError", "logStatusFatal",
                                        "logAll"};
    Instance *inst = glue_admit(c, F_SET_DEBUG_LOGGING);
    if (inst == NULL) return fmi2Error;
    for (size_t i = 0; i < nCategories; i++) {
        int found = 0;
        for (size_t k = 0; k < sizeof known / sizeof known[0]; k++)
            found |= categories != NULL && categories[i] != NULL && strcmp(categories[i], known[k]) == 0;
        if (!found) {
            glue_log(inst, fmi2Error, "fmi2SetDebugLogging: unknown log category '%s' (known: logStatusWarning, "
                     "logStatusDiscard, logStatusError, logStatusFatal, logAll)",
                     categories && categories[i] ? categories[i] : "(null)");
            return fmi2Error;
        }
    }
    inst->logging_on = loggingOn;
    return fmi2OK;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    (void)toleranceDefined, (void)tolerance;
    Instance *inst = glue_admit(c, F_SETUP_EXPERIMENT);
    if (inst == NULL) return fmi2Error;
    if (!isfinite(startTime) || (stopTimeDefined && !(stopTime >= startTime))) {
        glue_log(inst, fmi2Error, "fmi2SetupExperiment: startTime %.17g and stopTime %.17g must be finite with "
                 "stopTime >= startTime", startTime, stopTime);
        return fmi2Error;
    }
    inst->time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    Instance *inst = glue_admit(c, F_ENTER_INIT);
    if (inst == NULL) return fmi2Error;
    inst->fmi_state = S_INIT;
    inst->outputs_stale = 1;
    inst->outputs_read = 0;
    return fmi2OK;
}

static int blocked_by_invalid(Instance *inst, const char *call, Causality causality)
{
    for (size_t i = 0; i < MODEL_INFO.n_vars; i++)
        if (inst->invalid[i] && MODEL_INFO.vars[i].causality == causality) {
            char range[96];
            range_text(&MODEL_INFO.vars[i], range, sizeof range);
            glue_log(inst, fmi2Error, "%s: %s was given a value outside %s; set a valid value first", call,
                     MODEL_INFO.vars[i].name, range);
            return 1;
        }
    return 0;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    Instance *inst = glue_admit(c, F_EXIT_INIT);
    if (inst == NULL) return fmi2Error;
    if (blocked_by_invalid(inst, "fmi2ExitInitializationMode", CA_PARAMETER)) return fmi2Error;
    fmi2Status s = MODEL_INFO.initialize(inst);
    if (s > fmi2Warning) return s;
    inst->fmi_state = S_STEP_COMPLETE;
    inst->outputs_stale = MODEL_INFO.sample != NULL; /* feedthrough: the start sample is taken on the first read */
    return s;
}

fmi2Status fmi2Terminate(fmi2Component c)
{
    Instance *inst = glue_admit(c, F_TERMINATE);
    if (inst == NULL) return fmi2Error;
    inst->fmi_state = S_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c)
{
    Instance *inst = glue_admit(c, F_RESET);
    if (inst == NULL) return fmi2Error;
    reset_values(inst);
    inst->fmi_state = S_INSTANTIATED;
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    return get_values(c, vr, nvr, VT_REAL, value);
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[])
{
    double buf[64];
    fmi2Status s = fmi2OK;
    for (size_t k = 0; k < nvr && s <= fmi2Warning; k += 64) {
        size_t m = nvr - k < 64 ? nvr - k : 64;
        s = get_values(c, vr + k, m, VT_INTEGER, buf);
        for (size_t j = 0; j < m && s <= fmi2Warning; j++) value[k + j] = (fmi2Integer)buf[j];
    }
    return s;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[])
{
    double buf[64];
    fmi2Status s = fmi2OK;
    for (size_t k = 0; k < nvr && s <= fmi2Warning; k += 64) {
        size_t m = nvr - k < 64 ? nvr - k : 64;
        s = get_values(c, vr + k, m, VT_BOOLEAN, buf);
        for (size_t j = 0; j < m && s <= fmi2Warning; j++) value[k + j] = buf[j] != 0.0;
    }
    return s;
}

/* No variable of these FMUs is a String (a tool that cannot set strings uses them fully), yet FMI 2.0 requires the
   functions: an empty call is fine, any value reference refused, naming it. */
static fmi2Status no_strings(fmi2Component c, int access, const char *function, const fmi2ValueReference vr[],
                             size_t nvr, const void *value)
{
    Instance *inst = admit_as(c, access, function);
    if (inst == NULL) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    if (vr == NULL || value == NULL) {
        glue_log(inst, fmi2Error, "%s: vr[] and value[] must not be NULL", function);
        return fmi2Error;
    }
    glue_log(inst, fmi2Error, "%s: value reference %u: %s", function, (unsigned)vr[0],
             find_var(vr[0]) < 0 ? "no such variable" : "not a String variable (this FMU has none)");
    return fmi2Error;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[])
{
    return no_strings(c, F_GET, "fmi2GetString", vr, nvr, value);
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    return set_values(c, vr, nvr, VT_REAL, value);
}

static fmi2Status set_converted(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, VarType type,
                                const void *value)
{
    double *buf = malloc((nvr ? nvr : 1) * sizeof *buf);
    if (buf == NULL) return fmi2Error;
    for (size_t k = 0; k < nvr && value != NULL; k++)
        buf[k] = type == VT_INTEGER ? (double)((const fmi2Integer *)value)[k]
                                    : (double)(((const fmi2Boolean *)value)[k] != fmi2False);
    fmi2Status s = set_values(c, vr, nvr, type, value != NULL ? buf : NULL);
    free(buf);
    return s;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[])
{
    return set_converted(c, vr, nvr, VT_INTEGER, value);
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[])
{
    return set_converted(c, vr, nvr, VT_BOOLEAN, value);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[])
{
    return no_strings(c, F_SET, "fmi2SetString", vr, nvr, value);
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown, (void)dvUnknown;
    glue_log(as_instance(c), fmi2Error, "fmi2GetDirectionalDerivative: not provided by this FMU");
    return fmi2Error;
}

/* -- co-simulation ---------------------------------------------------------------------------- */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    (void)vr, (void)nvr, (void)order, (void)value;
    glue_log(as_instance(c), fmi2Error, "fmi2SetRealInputDerivatives: not provided (inputs are held over a step)");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    (void)vr, (void)nvr, (void)order, (void)value;
    glue_log(as_instance(c), fmi2Error, "fmi2GetRealOutputDerivatives: not provided by this FMU");
    return fmi2Error;
}

int glue_whole_samples(double h, double period, double *n)
{
    *n = nearbyint(h / period);
    return fabs(h - *n * period) <= GLUE_STEP_TOLERANCE ? 0 : -1;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    Instance *inst = glue_admit(c, F_DO_STEP);
    if (inst == NULL) return fmi2Error;
    if (!isfinite(currentCommunicationPoint) || !isfinite(communicationStepSize) || !(communicationStepSize > 0)) {
        glue_log(inst, fmi2Error, "fmi2DoStep: step_size = %.17g s at t = %.17g s: the step must be finite and > 0 "
                 "and t finite", communicationStepSize, currentCommunicationPoint);
        return fmi2Error;
    }
    if (communicationStepSize > GLUE_MAX_STEP_SIZE) {
        glue_log(inst, fmi2Error, "fmi2DoStep: step_size = %.17g s is longer than the longest communication step these "
                 "FMUs take, %g s (allowed: 0 < step_size <= %g s; split it)", communicationStepSize,
                 GLUE_MAX_STEP_SIZE, GLUE_MAX_STEP_SIZE);
        return fmi2Error;
    }
    if (blocked_by_invalid(inst, "fmi2DoStep", CA_INPUT)) return fmi2Error;
    if (inst->outputs_stale && MODEL_INFO.sample != NULL) { /* the sample of t, from the inputs present now */
        fmi2Status s = MODEL_INFO.sample(inst);
        if (s > fmi2Warning) return s;
        inst->outputs_stale = 0;
    }
    fmi2Status s = MODEL_INFO.do_step(inst, currentCommunicationPoint, communicationStepSize);
    if (s <= fmi2Warning) {
        inst->time = currentCommunicationPoint + communicationStepSize;
        inst->outputs_stale = MODEL_INFO.sample != NULL;
    } else if (s == fmi2Discard) { /* as the Python FMUs: the FMU stayed at t; fmi2Set* is refused until a state is
                                      restored (fmi2SetFMUstate) or the FMU is reset or terminated */
        inst->fmi_state = S_STEP_FAILED;
    }
    return s;
}

fmi2Status fmi2CancelStep(fmi2Component c)
{
    glue_log(as_instance(c), fmi2Error, "fmi2CancelStep: steps are synchronous, there is nothing to cancel");
    return fmi2Error;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    Instance *inst = glue_admit(c, F_STATUS);
    if (inst == NULL || value == NULL || s != fmi2DoStepStatus) return fmi2Discard;
    *value = fmi2OK;
    return fmi2OK;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    Instance *inst = glue_admit(c, F_STATUS);
    if (inst == NULL || value == NULL || s != fmi2LastSuccessfulTime) return fmi2Discard;
    *value = inst->time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    (void)s, (void)value;
    return glue_admit(c, F_STATUS) ? fmi2Discard : fmi2Error;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{
    Instance *inst = glue_admit(c, F_STATUS);
    if (inst == NULL || value == NULL || s != fmi2Terminated) return fmi2Discard;
    *value = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    (void)s, (void)value;
    return glue_admit(c, F_STATUS) ? fmi2Discard : fmi2Error;
}
