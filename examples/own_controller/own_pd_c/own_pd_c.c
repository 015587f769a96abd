/*
 * A user's controller for the flexarm-fmi arm in plain C (FMI 2.0 co-simulation, no Python): joint PD plus
 * the slew's feedforward, the same law as own_pd.py. A short standalone template: copy it, change
 * `torque()` and the variable table (here and in own_pd_c/modelDescription.xml, same value references).
 *
 *     tau_i = sat( ff * tau_i_ff + kp_i (q_i_ref[-d] - q_i_m) + kd_i (qd_i_ref[-d] - qd_i_m) ),  |tau_i| <= tau_i_max
 *
 * Direct feedthrough: fmi2GetReal computes the torques from the inputs set at this communication point.
 * d = loop_delay_samples (0..MAX_DELAY): samples between the plant state measured and the torques using it;
 * 0 in a Gauss-Seidel master, 2 per ms of step in a Jacobi one. With d > 0 the measurements are compared with
 * the reference present d samples before the last fmi2DoStep (kept in a ring, one entry per 1 ms sample;
 * the first one kept until d exist), the feedforward is the one present now (as own_pd.py).
 * Build: examples/own_controller/build_c.sh (gcc, zip) -> build/examples/OwnPDC.fmu.
 */
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

/* Value references: the order of modelDescription.xml's <ModelVariables>. */
enum { Q1_M, Q2_M, QD1_M, QD2_M, Q1_REF, Q2_REF, QD1_REF, QD2_REF, TAU1_FF, TAU2_FF,
       KP1, KD1, KP2, KD2, USE_FF, TAU1_MAX, TAU2_MAX, TAU1, TAU2, LOOP_DELAY, N_VARS };
static const double START[N_VARS] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 80.0, 0.25, 2.0, 0.01, 1, 7.0, 2.25, 0, 0, 0};
enum { FIRST_INPUT = Q1_M, FIRST_PARAMETER = KP1, FIRST_OUTPUT = TAU1 };
#define MAX_DELAY 10  /* loop_delay_samples allowed: 0..MAX_DELAY */
#define SAMPLE 1e-3   /* the reference's sample, s */

typedef struct {
    double v[N_VARS];
    double past[MAX_DELAY + 1][4]; /* q1_ref, q2_ref, qd1_ref, qd2_ref of the last samples (a ring) */
    int n_past, next;              /* entries kept (<= MAX_DELAY + 1), where the next one goes */
    fmi2CallbackLogger log;
    fmi2ComponentEnvironment env;
    char name[64];
} Model;

static double sat(double x, double limit) { return x < -limit ? -limit : (x > limit ? limit : x); }

static double torque(const Model *m, int joint) /* joint 0 or 1 */
{
    const double *v = m->v, *ref = &v[Q1_REF]; /* q1_ref, q2_ref, qd1_ref, qd2_ref: present, or d samples ago */
    int d = (int)v[LOOP_DELAY];
    if (d > 0 && m->n_past > 0) {
        int back = d < m->n_past - 1 ? d : m->n_past - 1;
        ref = m->past[(m->next - 1 - back + 2 * (MAX_DELAY + 1)) % (MAX_DELAY + 1)];
    }
    double tau = v[KP1 + 2 * joint] * (ref[joint] - v[Q1_M + joint])
               + v[KD1 + 2 * joint] * (ref[2 + joint] - v[QD1_M + joint]);
    if (v[USE_FF] != 0.0) tau += v[TAU1_FF + joint];
    return sat(tau, v[TAU1_MAX + joint]);
}

static fmi2Status refuse(Model *m, const char *what)
{
    if (m != NULL && m->log != NULL) m->log(m->env, m->name, fmi2Error, "logError", "%s", what);
    return fmi2Error;
}

/* ---- the FMI 2.0 co-simulation API ---- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[])
{
    (void)c, (void)on, (void)n, (void)cat;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resources,
                              const fmi2CallbackFunctions *cb, fmi2Boolean visible, fmi2Boolean logging)
{
    (void)guid, (void)resources, (void)visible, (void)logging;
    if (type != fmi2CoSimulation) return NULL;
    Model *m = calloc(1, sizeof *m);
    if (m == NULL) return NULL;
    memcpy(m->v, START, sizeof START);
    m->log = cb != NULL ? cb->logger : NULL;
    m->env = cb != NULL ? cb->componentEnvironment : NULL;
    strncpy(m->name, name != NULL ? name : "", sizeof m->name - 1);
    return m;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tol_on, fmi2Real tol, fmi2Real t0, fmi2Boolean stop_on,
                               fmi2Real t1)
{
    (void)c, (void)tol_on, (void)tol, (void)t0, (void)stop_on, (void)t1;
    return fmi2OK;
}
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    ((Model *)c)->n_past = ((Model *)c)->next = 0;
    return fmi2OK;
}
fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c)
{
    memcpy(((Model *)c)->v, START, sizeof START);
    ((Model *)c)->n_past = ((Model *)c)->next = 0;
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[])
{
    Model *m = c;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] >= N_VARS || vr[i] == USE_FF || vr[i] == LOOP_DELAY) return refuse(m, "fmi2GetReal: not a Real");
        value[i] = vr[i] == TAU1 ? torque(m, 0) : vr[i] == TAU2 ? torque(m, 1) : m->v[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[])
{
    Model *m = c;
    for (size_t i = 0; i < n; i++)
        if (vr[i] >= FIRST_OUTPUT || vr[i] == USE_FF) return refuse(m, "fmi2SetReal: not a Real input or parameter");
    for (size_t i = 0; i < n; i++) m->v[vr[i]] = value[i];
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean value[])
{
    for (size_t i = 0; i < n; i++) {
        if (vr[i] != USE_FF) return refuse(c, "fmi2GetBoolean: not a Boolean");
        value[i] = ((Model *)c)->v[USE_FF] != 0.0;
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean value[])
{
    for (size_t i = 0; i < n; i++)
        if (vr[i] != USE_FF) return refuse(c, "fmi2SetBoolean: not a Boolean");
    for (size_t i = 0; i < n; i++) ((Model *)c)->v[USE_FF] = value[i] ? 1.0 : 0.0;
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer value[])
{
    for (size_t i = 0; i < n; i++) {
        if (vr[i] != LOOP_DELAY) return refuse(c, "fmi2GetInteger: not an Integer");
        value[i] = (fmi2Integer)((Model *)c)->v[LOOP_DELAY];
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer value[])
{
    for (size_t i = 0; i < n; i++) {
        if (vr[i] != LOOP_DELAY) return refuse(c, "fmi2SetInteger: not an Integer");
        if (value[i] < 0 || value[i] > MAX_DELAY) return refuse(c, "loop_delay_samples: allowed 0..10");
    }
    for (size_t i = 0; i < n; i++) ((Model *)c)->v[LOOP_DELAY] = value[i];
    return fmi2OK;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean no_prior)
{
    (void)t, (void)no_prior;
    Model *m = c;
    long samples = h >= 0 ? (long)(h / SAMPLE + 0.5) : -1;
    double off = h - (double)samples * SAMPLE;
    if (samples < 0 || off > 1e-9 || off < -1e-9) return refuse(m, "fmi2DoStep: step_size: not a whole multiple of 1 ms");
    /* keep the reference present now, once per 1 ms sample of the step (the torques read a past one) */
    for (int k = 0; k < samples && k <= MAX_DELAY; k++) {
        memcpy(m->past[m->next], &m->v[Q1_REF], sizeof m->past[0]);
        m->next = (m->next + 1) % (MAX_DELAY + 1);
        if (m->n_past < MAX_DELAY + 1) m->n_past++;
    }
    return fmi2OK;
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[])
{
    (void)vr, (void)v;
    return n == 0 ? fmi2OK : refuse(c, "fmi2GetString: no String variables");
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[])
{
    (void)vr, (void)v;
    return n == 0 ? fmi2OK : refuse(c, "fmi2SetString: no String variables");
}
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)s; return refuse(c, "no FMU states"); }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { (void)s; return refuse(c, "no FMU states"); }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)s; return refuse(c, "no FMU states"); }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n)
{
    (void)s, (void)n;
    return refuse(c, "no FMU states");
}
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n)
{
    (void)s, (void)b, (void)n;
    return refuse(c, "no FMU states");
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s)
{
    (void)b, (void)n, (void)s;
    return refuse(c, "no FMU states");
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real dv[], fmi2Real dz[])
{
    (void)u, (void)nu, (void)z, (void)nz, (void)dv, (void)dz;
    return refuse(c, "no directional derivatives");
}
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    (void)vr, (void)n, (void)order, (void)value;
    return refuse(c, "no input derivatives");
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real value[])
{
    (void)vr, (void)n, (void)order, (void)value;
    return refuse(c, "no output derivatives");
}
fmi2Status fmi2CancelStep(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status *v)
{
    (void)k, (void)v;
    return refuse(c, "fmi2GetStatus: not supported");
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real *v)
{
    (void)k, (void)v;
    return refuse(c, "fmi2GetRealStatus: not supported");
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer *v)
{
    (void)k, (void)v;
    return refuse(c, "fmi2GetIntegerStatus: not supported");
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v)
{
    (void)k, (void)v;
    return refuse(c, "fmi2GetBooleanStatus: not supported");
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String *v)
{
    (void)k, (void)v;
    return refuse(c, "fmi2GetStringStatus: not supported");
}
