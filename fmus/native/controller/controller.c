/*
 * Native controller FMUs: flexarm.control.TrackingController in C, one source for every variant.
 *
 *     tau = sat( tau_ff(t_k) - K(t_k) (x_hat - x_hat_d(t_k)) ),  x_hat = E m
 *
 * m = (q1, q2, qd1, qd2, eps1..eps6) measured; E the rigid-bracket reconstruction (eqs. 21-31) with the
 * chosen theta7-rate estimate; x_hat_d = E m_d from the desired measurements; K the reduced gain of the
 * schedule's set in force. As the library, the law is evaluated as tau_ff - (K E m - K x_hat_d) with K E and
 * K x_hat_d precomputed. After the slew (k >= n_steps) it holds the final desired state with zero feedforward and
 * the last gains. The law's arithmetic (K E, K x_hat_d, the torque, the saturation, the schedule's switching rule)
 * is not written here: control_law_api.h's law_* functions are generated from flexarm/control_law.py
 * (fmu_build/law_codegen.py), the functions the Python FMU runs.
 *
 * controller_mode.h (generated per FMU) fixes the variant: CONTROLLER_FEEDFORWARD, CONTROLLER_FEEDBACK
 * (0/1) and the gains resource (continuous or discrete-time designs). Trajectory, estimators and gains are
 * resources (SHA-256 checked).
 *
 * A learned feedforward correction (flexarm.ilc) is read at initialisation from the FMU's resources
 * (learned_ff.c, LEARNED_FF_RESOURCE; checked against TRAJECTORY_SHA256 and PARAMETER_SHA256 of
 * learned_ff_data.h, the files this FMU was built from). Row k is added to the feedforward of sample k (k < m).
 *
 * The loop delay (docs/control.md, "The loop measures its own delay"; flexarm_controller_base.ControllerSlave):
 * the law above runs while the measurements present at fmi2DoStep are of the sample being committed (a
 * Gauss-Seidel master). From the first fmi2DoStep whose measurements are older (a Jacobi master reads the torques
 * before it sets them) the variants with feedback predict over the measured delay d (flexarm.lqg.PredictedTracking):
 * the LQG design's Kalman filter of the schedule (lqg_core.c, resources lqg_<schedule>.txt, lqg_trajectory.txt)
 * takes the measurement of sample k - d and predicts the error state x_k with the torques sent, and
 *     tau = sat( tau_ff(t_k) - K(t_k) x_k )
 * with the paper's reduced gain; no feedthrough then: the torques are computed at fmi2DoStep and held. The
 * samples up to the switch are run again from the trajectory alone with the torques the plant reported holding.
 * A master's placeholder (no index, every measurement exactly 0: fmpy's first step) is no measurement of q = 0:
 * the feedforward alone.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "control_law_api.h"
#include "controller_lqg.h"
#include "controller_mode.h"
#include "fmi2_glue.h"
#include "learned_ff.h"
#include "learned_ff_data.h"
#include "loop_index.h"
#include "lqg_resources.h"
#include "model_vars.h"

#define N_SETS 4
#if CONTROLLER_FEEDBACK
static const char *const LQG_FILES[N_SCHEDULES] = {SCHEDULE_FILE_LIST};
#endif
static const char *const SCHEDULE_LABELS[N_SCHEDULES] = {SCHEDULE_LABEL_LIST};
static const double SCHEDULE_PERIODS[N_SCHEDULES] = {SCHEDULE_PERIOD_LIST};

typedef struct {
    int count;
    double *times, *gains; /* count; count x 2 x 22 */
} Schedule;

typedef struct {
    int n_steps;
    double dt;
    double *feedforward;  /* (n_steps + 1) x 2 */
    double *desired;      /* (n_steps + 1) x 10 */
    double estimator[2][N_STATE * N_MEAS];
    Schedule schedules[N_SETS][N_SCHEDULES];
    /* derived for the configuration `key` */
    double key[5];
    int *gain_index;      /* n_steps + 1 */
    double *gain_per_meas; /* count x 2 x 10 */
    double *offsets;      /* (n_steps + 1) x 2 */
    double *correction;   /* n_correction x 2: the learned feedforward correction (NULL: none) */
    long n_correction;
    const Schedule *schedule; /* the gains in force (feedback variants) */
    LqgData lqg;          /* the predictor over a measured delay: trajectory, designs (feedback variants) */
    Noise noise[N_SCHEDULES];       /* each design's noise model: the predictor's time-varying filter */
    double predictor_prior; /* its prior covariance at sample 0, times the steady one (flexarm.lqg.PREDICTOR_PRIOR) */
    int predictor_schedule; /* the schedule in force: the predictor's design */
} ControllerData;

static int read_schedule(Instance *inst, const char *file, const char *text, int set, int s, Schedule *out)
{
    char label[64];
    double count;
    snprintf(label, sizeof label, "set%d_%s_count", set, SCHEDULE_LABELS[s]);
    if (glue_read_doubles(inst, file, text, label, &count, 1)) return -1;
    out->count = (int)count;
    out->times = malloc((size_t)out->count * sizeof(double));
    out->gains = malloc((size_t)out->count * 2 * N_STATE * sizeof(double));
    if (out->times == NULL || out->gains == NULL) return -1;
    snprintf(label, sizeof label, "set%d_%s_times", set, SCHEDULE_LABELS[s]);
    if (glue_read_doubles(inst, file, text, label, out->times, (size_t)out->count)) return -1;
    snprintf(label, sizeof label, "set%d_%s_gains", set, SCHEDULE_LABELS[s]);
    return glue_read_doubles(inst, file, text, label, out->gains, (size_t)out->count * 2 * N_STATE);
}

#if CONTROLLER_FEEDBACK /* the predictor and its resources: the feedback variants only */
/* The predictor's trajectory and the design of schedule s (resources of the feedback variants,
   fmu_build/native_resources.py), read at the first delay measured (MODEL_INFO.on_demand: a run with none reads
   and hashes none of them); 0, or -1 after logging why. */
static int load_predictor(Instance *inst, LqgData *p, Noise *noise, double *prior, int s)
{
    const char *const when = "fmi2DoStep (the predictor over the measured loop delay)";
    size_t size;
    if (p->index == NULL) {
        const char *file = LQG_TRAJECTORY_FILE;
        char *text = glue_read_resource(inst, file, when, &size);
        double n;
        int rc = text == NULL || glue_read_doubles(inst, file, text, "n_steps", &n, 1) ||
                 glue_read_doubles(inst, file, text, "dt", &p->dt, 1);
        if (rc == 0) {
            p->n_steps = (int)n;
            p->feedforward = lqg_read_array(inst, file, text, "feedforward_torque", (size_t)(p->n_steps + 1) * 2);
            p->desired = lqg_read_array(inst, file, text, "desired_measurements", (size_t)(p->n_steps + 1) * N_MEAS);
            rc = !p->feedforward || !p->desired || glue_read_doubles(inst, file, text, "predictor_prior", prior, 1);
            if (rc == 0) p->index = calloc((size_t)p->n_steps + 1, sizeof *p->index);
            rc = rc || p->index == NULL;
        }
        free(text);
        if (rc) {
            free(p->feedforward), free(p->desired), free(p->index);
            p->feedforward = p->desired = NULL, p->index = NULL;
            return -1;
        }
    }
    if (p->designs[s].times == NULL) {
        char *text = glue_read_resource(inst, LQG_FILES[s], when, &size);
        int rc = text == NULL || lqg_read_design(inst, LQG_FILES[s], text, &p->designs[s], p->c) ||
                 lqg_read_noise(inst, LQG_FILES[s], text, p->designs[s].count, &noise[s]);
        free(text);
        if (rc) { /* read again (and refused again) at the next switch */
            lqg_free_design(&p->designs[s]), free(noise[s].w), noise[s].w = NULL;
            return -1;
        }
    }
    return 0;
}

/* Read by load_predictor when first needed, not at fmi2Instantiate. */
static const char *const ON_DEMAND[] = {LQG_TRAJECTORY_FILE, SCHEDULE_FILE_LIST, NULL};
#endif

static void controller_unload(Instance *inst)
{
    ControllerData *d = inst->data;
    if (d == NULL) return;
    free(d->feedforward), free(d->desired), free(d->gain_index), free(d->gain_per_meas), free(d->offsets);
    free(d->correction);
    for (int i = 0; i < N_SETS; i++)
        for (int s = 0; s < N_SCHEDULES; s++) free(d->schedules[i][s].times), free(d->schedules[i][s].gains);
    free(d->lqg.feedforward), free(d->lqg.desired), free(d->lqg.index);
    for (int s = 0; d->lqg.designs != NULL && s < N_SCHEDULES; s++) lqg_free_design(&d->lqg.designs[s]), free(d->noise[s].w);
    free(d->lqg.designs), lqg_free_gains(&d->lqg);
    free(d);
    inst->data = NULL;
}

static int controller_load(Instance *inst, char *const *contents, const size_t *sizes)
{
    (void)sizes;
    ControllerData *d = calloc(1, sizeof *d);
    if (d == NULL) return -1;
    inst->data = d;
    int traj = -1, gains = -1;
    for (size_t r = 0; r < MODEL_INFO.n_resources; r++) {
        if (strcmp(MODEL_INFO.resources[r].file, "trajectory.txt") == 0) traj = (int)r;
        if (strcmp(MODEL_INFO.resources[r].file, "gains.txt") == 0) gains = (int)r;
    }
    if (traj < 0 || (CONTROLLER_FEEDBACK && gains < 0)) goto fail;
    const char *file = MODEL_INFO.resources[traj].file, *text = contents[traj];
    double n;
    if (glue_read_doubles(inst, file, text, "n_steps", &n, 1) || glue_read_doubles(inst, file, text, "dt", &d->dt, 1))
        goto fail;
    d->n_steps = (int)n;
    d->feedforward = malloc((size_t)(d->n_steps + 1) * 2 * sizeof(double));
    d->desired = malloc((size_t)(d->n_steps + 1) * N_MEAS * sizeof(double));
    d->gain_index = calloc((size_t)d->n_steps + 1, sizeof(int));
    d->offsets = calloc((size_t)(d->n_steps + 1) * 2, sizeof(double));
    if (!d->feedforward || !d->desired || !d->gain_index || !d->offsets ||
        glue_read_doubles(inst, file, text, "feedforward_torque", d->feedforward, (size_t)(d->n_steps + 1) * 2) ||
        glue_read_doubles(inst, file, text, "desired_measurements", d->desired, (size_t)(d->n_steps + 1) * N_MEAS) ||
        glue_read_doubles(inst, file, text, "estimator_1", d->estimator[0], N_STATE * N_MEAS) ||
        glue_read_doubles(inst, file, text, "estimator_2", d->estimator[1], N_STATE * N_MEAS))
        goto fail;
#if CONTROLLER_FEEDBACK
    for (int i = 0; i < N_SETS; i++)
        for (int s = 0; s < N_SCHEDULES; s++)
            if (read_schedule(inst, MODEL_INFO.resources[gains].file, contents[gains], i + 1, s, &d->schedules[i][s]))
                goto fail;
    d->lqg.designs = calloc(3, sizeof *d->lqg.designs); /* each read by load_predictor when first needed */
    if (d->lqg.designs == NULL) goto fail;
#else
    (void)read_schedule;
#endif
    d->key[0] = -1;
    return 0;
fail:
    controller_unload(inst);
    return -1;
}

/* Read the learned correction in the resources into d->correction (none without the file); fmi2Error naming the
   file and the reason. */
static fmi2Status load_correction(Instance *inst)
{
    ControllerData *d = inst->data;
    free(d->correction), d->correction = NULL, d->n_correction = 0;
    fmi2Status status = learned_ff_load(inst, TRAJECTORY_SHA256, PARAMETER_SHA256, &d->correction, &d->n_correction);
    if (status == fmi2OK && d->correction != NULL && !CONTROLLER_FEEDFORWARD) {
        glue_log(inst, fmi2Error, "resources/%s: this controller has no feedforward to correct", LEARNED_FF_RESOURCE);
        free(d->correction), d->correction = NULL, d->n_correction = 0;
        return fmi2Error;
    }
    return status;
}

static int schedule_of(double period)
{
    for (int s = 0; s < N_SCHEDULES; s++)
        if (fabs(period - SCHEDULE_PERIODS[s]) <= 1e-12) return s;
    return -1;
}

/* K E and K x_hat_d for the current parameters (once per configuration). */
static fmi2Status configure(Instance *inst)
{
    ControllerData *d = inst->data;
    double key[5] = {VALUE(inst, IDX_gain_set), VALUE(inst, IDX_schedule_period), VALUE(inst, IDX_omega7_estimate),
                     VALUE(inst, IDX_tau1_max), VALUE(inst, IDX_tau2_max)};
    int s = schedule_of(key[1]);
    if (s < 0) {
        glue_log(inst, fmi2Error, "schedule_period: %.17g s is not one of 0.2, 0.02 or 0 (one gain set)", key[1]);
        return fmi2Error;
    }
    if (memcmp(key, d->key, sizeof key) == 0) return fmi2OK;
#if CONTROLLER_FEEDBACK
    const Schedule *sch = &d->schedules[(int)key[0] - 1][s];
    d->schedule = sch;
    d->predictor_schedule = s; /* the predictor's filter, of the same schedule: read and made at the switch */
    lqg_free_gains(&d->lqg);
    const double *est = d->estimator[(int)key[2] - 1];
    free(d->gain_per_meas);
    d->gain_per_meas = malloc((size_t)sch->count * 2 * N_MEAS * sizeof(double));
    if (d->gain_per_meas == NULL) return fmi2Error;
    for (int g = 0; g < sch->count; g++) /* K E */
        law_gain_on_measurements(sch->gains + (size_t)g * 2 * N_STATE, est, d->gain_per_meas + (size_t)g * 2 * N_MEAS);
    lqg_schedule_index(sch->times, sch->count, d->n_steps, d->dt, d->gain_index); /* the set in force */
    for (int k = 0; k <= d->n_steps; k++) /* K x_hat_d */
        law_gain_offset(sch->gains + (size_t)d->gain_index[k] * 2 * N_STATE, est, d->desired + (size_t)k * N_MEAS,
                        d->offsets + (size_t)k * 2);
#endif
    memcpy(d->key, key, sizeof key);
    return fmi2OK;
}

typedef struct { /* the FMU state (flat: copied by fmi2Get/SetFMUstate) */
    int delay_contradictions; /* what the log says once per run */
    int delay;                /* the measured loop delay the law predicts over (0: none measured, the paper's law) */
    LqgState committed;       /* delay > 0: the predictor after the last sample run */
    double held[2], held_index[4]; /* delay > 0: the torques of the last sample run and their index outputs */
    double start; /* the master's sample at which the trajectory's sample 0 runs (lqg_starts_late): 0 or 1 */
    double foreign[LQG_N_FOREIGN][3];  /* sample, torques the plant reported holding (lqg_plant_applied) */
    int n_foreign;
    long long switch_end; /* 1 + the last sample whose torque the law before the switch published */
} ControllerState;

/* The feedforward of sample k: the trajectory's (zero after the slew) plus the learned correction. */
static void feedforward(const ControllerData *d, long k, double tau[2])
{
    tau[0] = tau[1] = 0.0;
#if CONTROLLER_FEEDFORWARD
    if (k < d->n_steps) tau[0] = d->feedforward[2 * k], tau[1] = d->feedforward[2 * k + 1];
    if (k < d->n_correction) { /* flexarm.control_law.corrected_feedforward */
        const double nominal[2] = {tau[0], tau[1]};
        law_corrected_feedforward(nominal, d->correction + 2 * k, tau);
    }
#else
    (void)d, (void)k;
#endif
}

static fmi2Status controller_sample(Instance *inst)
{
    ControllerData *d = inst->data;
    ControllerState *st = inst->state;
    fmi2Status status = configure(inst);
    if (status != fmi2OK) return status;
    if (st->delay > 0) { /* predicting over a measured delay: the torques computed at the last fmi2DoStep */
        lqg_set_outputs(inst, st->held, st->held_index);
        return fmi2OK;
    }
    long k = lround(inst->time / d->dt) - (long)st->start; /* the trajectory's sample */
    if (k < 0) k = 0;
    int kc = k < d->n_steps ? (int)k : d->n_steps;
    double ff[2], tau[2], m[N_MEAS];
    feedforward(d, k, ff);
    lqg_measurements(inst, m);
    const double index = loop_trajectory_index(VALUE(inst, IDX_sample_index_m), st->start);
    const double limit[2] = {VALUE(inst, IDX_tau1_max), VALUE(inst, IDX_tau2_max)};
#if CONTROLLER_FEEDBACK
    /* fmpy's first step: no sample yet, not a measurement of q = 0; an index naming an earlier sample (a Jacobi
       master's first step, before fmi2DoStep has measured the delay): no measurement of sample k either */
    if (!loop_is_placeholder(index, m, N_MEAS) && !(loop_measured_delay((double)k, index) >= 1.0))
        law_tracking_torque(ff, d->gain_per_meas + (size_t)d->gain_index[kc] * 2 * N_MEAS, m, d->offsets + kc * 2,
                            limit, tau);
    else
        law_saturate(ff, limit, tau);
#else
    (void)kc;
    law_saturate(ff, limit, tau);
#endif
    const double out[4] = {loop_index_of_time(((double)k + st->start) * d->dt), /* the torques' sample (master's) */
                           loop_measured_delay((double)k, index), 0.0, /* the paper's law: no delay */
                           loop_index_of_time(st->start * d->dt)};
    lqg_set_outputs(inst, tau, out);
    return fmi2OK;
}

#if CONTROLLER_FEEDBACK
/* One sample of the predicting law (flexarm.lqg.PredictedTracking.step): x_k from the measurement of k - d, then
   the paper's law on the measurement predicted for k, tau = sat(tau_ff(k) - K(t_k) E C x_k); `next` the state
   after it. */
static void predicted_step(Instance *inst, const LqgState *s, long long k, const double m[N_MEAS], double tau[2],
                           LqgState *next)
{
    ControllerData *d = inst->data;
    const int dl = d->lqg.delay;
    double x_post[N_STATE], x_now[N_STATE], dy[N_MEAS], ff[2], nominal[2], command[2];
    static const double no_offset[2] = {0.0, 0.0}; /* the deviation C x_k is already about the trajectory */
    lqg_estimate(&d->lqg, s, k, m, x_post, x_now);
    const long kc = k < d->n_steps ? (long)k : d->n_steps;
    feedforward(d, (long)k, ff);
    law_measured(d->lqg.c, x_now, dy); /* the predicted measurement's deviation (flexarm.filter_law.measured) */
    const double limit[2] = {VALUE(inst, IDX_tau1_max), VALUE(inst, IDX_tau2_max)};
    law_tracking_torque(ff, d->gain_per_meas + (size_t)d->gain_index[kc] * 2 * N_MEAS, dy, no_offset, limit, tau);
    lqg_feedforward(&d->lqg, k, nominal, command); /* the filter's input: the deviation from the nominal */
    memset(next, 0, sizeof *next);
    for (int row = 0; row < dl; row++) next->du[row][0] = s->du[row + 1][0], next->du[row][1] = s->du[row + 1][1];
    next->du[dl][0] = tau[0] - nominal[0], next->du[dl][1] = tau[1] - nominal[1];
    memcpy(next->x_post[0], x_post, sizeof x_post);
    next->xi[0] = s->xi[0], next->xi[1] = s->xi[1];
    next->k = k + 1;
    next->started = 1;
}

/* Run sample committed.k of the predicting law from measurements m carrying `index` and hold its torques. Before
   sample d there is no measurement (y_d(0)); m NULL or a master's placeholder is none either (y_d of its sample). */
static void delayed_sample(Instance *inst, const double *m_present, double index)
{
    ControllerData *d = inst->data;
    ControllerState *st = inst->state;
    const long long k = st->committed.k;
    const double *m = m_present;
    if (k < st->delay) m = d->lqg.desired, index = LOOP_NO_SAMPLE;
    else if (m == NULL || loop_is_placeholder(index, m, N_MEAS))
        m = d->lqg.desired + lqg_clamp(&d->lqg, k - st->delay) * N_MEAS, index = LOOP_NO_SAMPLE;
    LqgState next;
    predicted_step(inst, &st->committed, k, m, st->held, &next);
    st->committed = next;
    st->held_index[0] = loop_index_of_time(((double)k + st->start) * d->dt);
    st->held_index[1] = loop_measured_delay((double)k, index);
    st->held_index[2] = (double)st->delay;
    st->held_index[3] = loop_index_of_time(st->start * d->dt);
    lqg_set_outputs(inst, st->held, st->held_index);
}

/* From fmi2DoStep(t_k) on, predict over `delay` without feedthrough: samples 0 .. k again from the trajectory
   alone with the torques the plant reported holding, then k + 1 .. k + n from the inputs present. */
static void switch_delay(Instance *inst, double t, long long k, int delay, double n, const double m[N_MEAS],
                         double index)
{
    ControllerData *d = inst->data;
    ControllerState *st = inst->state;
    st->delay = d->lqg.delay = delay;
    st->switch_end = k + 1;
    glue_log(inst, fmi2OK, "the loop delay measured at fmi2DoStep(t = %.17g s) is %d samples (the master reads the "
             "torques before it sets the measurements); predicting the state over it with the linearised model along "
             "the slew (Kalman filter) from sample %lld on", t, delay, k + 1);
    memset(&st->committed, 0, sizeof st->committed);
    for (long long s = 0; s <= k; s++) {
        delayed_sample(inst, NULL, LOOP_NO_SAMPLE);
        for (int i = 0; i < st->n_foreign; i++)
            if (st->foreign[i][0] == (double)s) lqg_with_applied(&d->lqg, &st->committed, s, &st->foreign[i][1]);
    }
    for (double i = 0; i < n; i++) delayed_sample(inst, m, index);
}

/* The predictor of the schedule in force: its design (read on first use), schedule index and time-varying gains;
   0, or -1 after logging why. */
static int predictor_ready(Instance *inst)
{
    ControllerData *d = inst->data;
    const int s = d->predictor_schedule;
    if (load_predictor(inst, &d->lqg, d->noise, &d->predictor_prior, s)) return -1;
    d->lqg.design = &d->lqg.designs[s];
    lqg_schedule_index(d->lqg.design->times, d->lqg.design->count, d->lqg.n_steps, d->lqg.dt, d->lqg.index);
    return lqg_transient_gains(inst, &d->lqg, &d->noise[s], d->predictor_prior);
}
#endif

static fmi2Status controller_initialize(Instance *inst)
{
    memset(inst->state, 0, sizeof(ControllerState)); /* the paper's law, no delay measured */
    fmi2Status status = configure(inst);
    if (status != fmi2OK) {
        glue_log(inst, fmi2Error, "fmi2ExitInitializationMode: schedule_period must be 0.2, 0.02 or 0");
        return status;
    }
    status = load_correction(inst);
    if (status != fmi2OK) return status;
    return controller_sample(inst);
}

static fmi2Status controller_do_step(Instance *inst, double t, double h)
{
    ControllerData *d = inst->data;
    double n;
    if (glue_whole_samples(h, d->dt, &n)) {
        glue_log(inst, fmi2Error, "fmi2DoStep: step_size: %.17g s at t = %.17g s is not a whole multiple of the "
                 "controller's sample (%g s, the trajectory's sample time, within %g s)", h, t, d->dt,
                 GLUE_STEP_TOLERANCE);
        return fmi2Error;
    }
    if (n == 0) return fmi2OK; /* no sample instant in the step: nothing changes */
    ControllerState *st = inst->state;
    if (lqg_starts_late(inst, t, d->dt, &st->start)) return fmi2OK; /* no sample of the slew in this step */
#if CONTROLLER_FEEDBACK
    const double k = nearbyint(t / d->dt) - st->start;
    const double index = loop_trajectory_index(VALUE(inst, IDX_sample_index_m), st->start);
    if ((st->delay > 0 || loop_measured_delay(k, index) >= 1.0) && d->lqg.gains == NULL &&
        predictor_ready(inst))
        return fmi2Error; /* the predictor's design and time-varying filter, once per configuration */
    if (lqg_gains_through(inst, &d->lqg, (long long)(k + n)))
        return fmi2Error; /* the filter's gains through the last sample of this step (made once per configuration) */
    double m[N_MEAS], applied[2];
    lqg_measurements(inst, m); /* present at fmi2DoStep, held in the step */
    const int foreign = lqg_plant_applied(inst, (long long)k, st->delay == 0 || k <= (double)st->switch_end, applied);
    if (foreign) lqg_remember(st->foreign, &st->n_foreign, (long long)k - 1, applied);
    if (st->delay > 0) { /* samples k + 1 .. k + n; the last one's torques are published */
        d->lqg.delay = st->delay; /* (after fmi2SetFMUstate) */
        if (k + 1 != (double)st->committed.k) {
            glue_log(inst, fmi2Error, "fmi2DoStep: current_time: %.17g s is sample %.0f, but the controller computed "
                     "sample %lld last (one fmi2DoStep per communication point, from t = 0)", t, k,
                     st->committed.k - 1);
            return fmi2Error;
        }
        if (foreign) lqg_with_applied(&d->lqg, &st->committed, (long long)k - 1, applied);
        for (double i = 0; i < n; i++) delayed_sample(inst, m, index);
        const double measured = st->held_index[1];
        if (measured >= 0.0 && measured != (double)st->delay && st->delay_contradictions++ == 0)
            glue_log(inst, fmi2Warning, "loop delay contradiction at t = %.17g s: the measurements present at "
                     "fmi2DoStep are of the plant's sample %g sample(s) before the one the torques are for "
                     "(tau_index - sample_index_m), but the law predicts over %d (the delay measured at the switch); "
                     "the master's stepping changed during the run", t, measured, st->delay);
        return fmi2OK;
    }
    const double measured = loop_measured_delay(k, index);
    if (measured >= 1.0) /* the master sets the measurements after it reads the torques: predict over the delay */
        switch_delay(inst, t, (long long)k, measured + n < MAX_DELAY ? (int)(measured + n) : MAX_DELAY, n, m, index);
#endif
    return fmi2OK; /* the paper's law: the torque is a function of the time and the inputs */
}

const ModelInfo MODEL_INFO = {
    MODEL_IDENTIFIER_STRING, MODEL_GUID_STRING, MODEL_VARS, MODEL_N_VARS, MODEL_RESOURCES, MODEL_N_RESOURCES,
    sizeof(ControllerState), controller_load, controller_unload, controller_initialize, controller_sample,
    controller_do_step,
#if CONTROLLER_FEEDBACK
    ON_DEMAND,
#else
    NULL,
#endif
};
