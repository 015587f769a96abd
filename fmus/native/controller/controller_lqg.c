/*
 * Native LQG controller FMU: flexarm.lqg.LqgController in C, stepped as fmus/controller/flexarm_controller_lqg_fmu.py.
 *
 * Per 1 ms sample k, with d = loop_delay_samples, j = max(k - d, 0), c(i) = min(i, n_steps) and the design
 * point in force at each sample (Phi, Gamma, M, K of the schedule; delta = minus the desired value):
 *   1. time update to j:     x = Phi x_post + Gamma du_(j-1)            (once the filter has started and k >= d)
 *   2. measurement update:   x_post = x + M (dm - C x),  dm = m - y_d(c(j))
 *   3. predictor to k:       x_now = x_post, then x_now = Phi x_now + Gamma du_i for the torques sent at j .. k-1
 *   4. torque:               tau = sat(tau_ff(k) + u(k) - K x_now - K_xi xi)    (tau_ff = 0 after the slew; u the
 *                            learned correction in resources/learned_feedforward.npz, learned_ff.c; zero without)
 *   5. integral action:      xi += dt C_q x_now, only in a sample whose torque does not saturate (anti-windup)
 * The torque deviations tau - tau_ff of the last d + 1 samples (the correction included) are kept for steps 1, 3.
 *
 * FMU stepping (as the Python FMU; docs/control.md, "Sampling and the loop delay"): the torques are a pure
 * function of the committed state and, with d = 0 only, of the inputs present; reads change nothing.
 *   d = 0: direct feedthrough. The torques at t_k are sample k from the measurements present (into a "pending"
 *          state); fmi2DoStep commits the sample of the inputs present then and runs the n - 1 samples inside
 *          a step of n ms with them held.
 *   d > 0: no direct feedthrough. fmi2DoStep(t_k, n ms) runs samples k + 1 .. k + n from the inputs present
 *          (held) and holds the torques of the last one until the next fmi2DoStep; sample 0 is computed at
 *          initialisation. A measurement at sample s < d (of the plant before t = 0) does not exist: the filter
 *          gets the desired measurement of t = 0 (zero innovation), so the start depends on no master.
 * A step of 0 samples (within 1e-9 s) does nothing. The
 * resources (fmu_build/native_resources.py): the trajectory and the designs of the three schedules, IEEE-754 bit patterns,
 * SHA-256 checked by the glue.
 *
 * estimator = 2 (payload_bank) runs the bank of lqg_bank.c (flexarm.lqg_bank.BankController) instead of the
 * single filter, with the same stepping.
 */
#include <math.h>
#include <stdlib.h>
#include <stdio.h>
#include <string.h>

#include "fmi2_glue.h"
#include "model_vars.h"

#include "control_law_api.h"
#include "controller_lqg.h"
#include "learned_ff.h"
#include "learned_ff_data.h"
#include "loop_index.h"
#include "lqg_resources.h"

static const char *const SCHEDULE_FILES[N_SCHEDULES] = {SCHEDULE_FILE_LIST};
static const double SCHEDULE_PERIODS[N_SCHEDULES] = {SCHEDULE_PERIOD_LIST};
#define BANK_FILE LQG_BANK_FILE
#define ESTIMATOR_KALMAN 1
#define ESTIMATOR_PAYLOAD_BANK 2


typedef struct { /* the FMU state (flat: copied by fmi2Get/SetFMUstate) */
    LqgState committed; /* after the last sample run */
    LqgState pending;   /* d = 0: after the sample the outputs show (derived from committed and the inputs) */
    double held[2];     /* d > 0: the torques of the last sample run, N.m */
    double held_index[4]; /* d > 0: their tau_index, loop_delay, loop_delay_assumed, slew_start_index */
    double start;       /* the master's sample at which the trajectory's sample 0 runs (lqg_starts_late): 0 or 1 */
    int delay;          /* loop_delay_samples = -1 (automatic): the delay the law predicts over (0 until measured) */
    int delay_contradictions, unwired_warned; /* what the log says once per run */
    double foreign[LQG_N_FOREIGN][3]; /* sample, torques: the plant held another torque than this law's (tau_lag != 0) */
    int n_foreign;
    long long switch_end; /* automatic: 1 + the last sample whose torque the law before the switch published */
} FmuState;

/* -- resources -------------------------------------------------------------------------------------------- */
static void lqg_unload(Instance *inst)
{
    LqgData *d = inst->data;
    if (d == NULL) return;
    free(d->feedforward), free(d->desired), free(d->index), free(d->correction);
    for (int s = 0; d->designs != NULL && s < N_SCHEDULES; s++) lqg_free_design(&d->designs[s]);
    free(d->designs);
    bank_free(&d->bank);
    free(d);
    inst->data = NULL;
}

static int lqg_load(Instance *inst, char *const *contents, const size_t *sizes)
{
    (void)sizes;
    LqgData *d = calloc(1, sizeof *d);
    if (d == NULL) return -1;
    inst->data = d;
    d->designs = calloc(N_SCHEDULES, sizeof *d->designs); /* each read by configure when first in force */
    if (d->designs == NULL) goto fail;
    for (size_t r = 0; r < MODEL_INFO.n_resources; r++) {
        const char *file = MODEL_INFO.resources[r].file, *text = contents[r];
        if (strcmp(file, LQG_TRAJECTORY_FILE) == 0) {
            double n;
            if (glue_read_doubles(inst, file, text, "n_steps", &n, 1) ||
                glue_read_doubles(inst, file, text, "dt", &d->dt, 1))
                goto fail;
            d->n_steps = (int)n;
            d->feedforward = lqg_read_array(inst, file, text, "feedforward_torque", (size_t)(d->n_steps + 1) * 2);
            d->desired = lqg_read_array(inst, file, text, "desired_measurements", (size_t)(d->n_steps + 1) * N_MEAS);
            d->index = calloc((size_t)d->n_steps + 1, sizeof *d->index);
            if (!d->feedforward || !d->desired || !d->index) goto fail;
        }
    }
    if (d->index == NULL) {
        glue_log(inst, fmi2Error, "fmi2Instantiate: resource " LQG_TRAJECTORY_FILE " missing from the build");
        goto fail;
    }
    d->key[0] = -1;
    return 0;
fail:
    lqg_unload(inst);
    return -1;
}

/* Read by configure when first in force (a run reads and hashes only the design and bank it uses). */
static const char *const ON_DEMAND[] = {SCHEDULE_FILE_LIST, BANK_FILE, NULL};

/* The design of schedule s and, with `bank`, the payload bank: read on first use; 0, or -1 after logging why. */
static int load_in_force(Instance *inst, int s, int bank)
{
    LqgData *d = inst->data;
    char when[96];
    size_t size;
    snprintf(when, sizeof when, "schedule_period = %g s%s", SCHEDULE_PERIODS[s],
             bank ? ", estimator = 2 (payload_bank)" : "");
    if (d->designs[s].times == NULL) {
        char *text = glue_read_resource(inst, SCHEDULE_FILES[s], when, &size);
        int rc = text == NULL || lqg_read_design(inst, SCHEDULE_FILES[s], text, &d->designs[s], d->c);
        free(text);
        if (rc) {
            lqg_free_design(&d->designs[s]); /* read again (and refused again) at the next configuration */
            return -1;
        }
    }
    if (bank && d->bank.times == NULL) {
        char *text = glue_read_resource(inst, BANK_FILE, when, &size);
        int rc = text == NULL || bank_load(inst, BANK_FILE, text, d);
        free(text);
        if (rc) {
            bank_free(&d->bank);
            return -1;
        }
    }
    return 0;
}

/* Torques of sample k from measurements m and the state s after k - 1; `next` the state after k. */
static void lqg_step(const LqgData *d, const LqgState *s, long long k, const double m[N_MEAS], const double limit[2],
                     double tau[2], LqgState *next)
{
    const Design *g = d->design;
    const int dl = d->delay;
    memset(next, 0, sizeof *next); /* the bank's rows unused */
    double x_post[N_STATE], x_now[N_STATE];
    lqg_estimate(d, s, k, m, x_post, x_now); /* 1 - 3 */
    const int i_k = d->index[lqg_clamp(d, k)]; /* 4 */
    double ff[2], ff_cmd[2];
    lqg_feedforward(d, k, ff, ff_cmd);
    double free_tau[2]; /* flexarm.filter_law.free_torque, control_law.saturate, filter_law.integrated */
    if (d->integral) { /* the augmented gain's two blocks, split at reading */
        const size_t at = (size_t)i_k * N_WEIGHTS + d->weight;
        law_free_torque_integral(ff_cmd, g->k_integral + at * 2 * N_STATE, x_now, g->k_xi + at * 2 * 2, s->xi,
                                 free_tau);
    } else {
        law_free_torque(ff_cmd, g->k + ((size_t)i_k * N_WEIGHTS + d->weight) * 2 * N_STATE, x_now, free_tau);
    }
    law_saturate(free_tau, limit, tau);
    if (d->integral) /* 5: C's first two rows map the state to the joint angles */
        law_integrated(s->xi, &d->dt, d->c, x_now, tau, free_tau, next->xi);
    else
        next->xi[0] = s->xi[0], next->xi[1] = s->xi[1];
    for (int row = 0; row < dl; row++) next->du[row][0] = s->du[row + 1][0], next->du[row][1] = s->du[row + 1][1];
    next->du[dl][0] = tau[0] - ff[0], next->du[dl][1] = tau[1] - ff[1];
    memcpy(next->x_post[0], x_post, sizeof x_post);
    next->k = k + 1;
    next->started = 1;
}

/* -- FMI side ------------------------------------------------------------------------------------------------- */
/* The estimator, design, weights and schedule index of the current parameters (recomputed when they change). */
static fmi2Status configure(Instance *inst)
{
    LqgData *d = inst->data;
    const FmuState *st = inst->state;
    const double requested = VALUE(inst, IDX_loop_delay_samples); /* automatic: the delay measured so far */
    double key[5] = {VALUE(inst, IDX_gain_set), VALUE(inst, IDX_schedule_period),
                     requested == LOOP_AUTOMATIC ? (double)st->delay : requested, VALUE(inst, IDX_integral_action),
                     VALUE(inst, IDX_estimator)};
    int s = -1;
    for (int i = 0; i < N_SCHEDULES; i++)
        if (fabs(key[1] - SCHEDULE_PERIODS[i]) <= 1e-12) s = i;
    if (s < 0) {
        glue_log(inst, fmi2Error, "gain_set = %g, schedule_period = %.17g s, loop_delay_samples = %g: schedule_period: "
                 "%.17g s is not one of 0.2, 0.02 or 0 (one gain set)", key[0], key[1], key[2], key[1]);
        return fmi2Error;
    }
    if (key[4] != ESTIMATOR_KALMAN && key[4] != ESTIMATOR_PAYLOAD_BANK) {
        glue_log(inst, fmi2Error, "estimator = %g: not one of 1 (kalman), 2 (payload_bank)", key[4]);
        return fmi2Error;
    }
    if (load_in_force(inst, s, key[4] == ESTIMATOR_PAYLOAD_BANK)) return fmi2Error;
    if (key[4] == ESTIMATOR_PAYLOAD_BANK && fabs(key[1] - d->bank.schedule_period) > 1e-12) {
        glue_log(inst, fmi2Error, "estimator = 2 (payload_bank), schedule_period = %.17g s: the payload bank exists "
                 "for schedule_period = %g s only (set schedule_period = %g, or estimator = 1 (kalman))", key[1],
                 d->bank.schedule_period, d->bank.schedule_period);
        return fmi2Error;
    }
    if (memcmp(key, d->key, sizeof key) == 0) return fmi2OK;
    d->design = &d->designs[s];
    d->weight = (int)key[0] - 1;
    d->delay = (int)key[2];
    d->integral = key[3] != 0.0;
    d->use_bank = key[4] == ESTIMATOR_PAYLOAD_BANK;
    lqg_schedule_index(d->design->times, d->design->count, d->n_steps, d->dt, d->index);
    memcpy(d->key, key, sizeof key);
    return fmi2OK;
}

/* One sample of the configured estimator's law. */
static void law_step(const LqgData *d, const LqgState *s, long long k, const double m[N_MEAS], const double limit[2],
                     double tau[2], LqgState *next)
{
    if (d->use_bank) bank_step(d, s, k, m, limit, tau, next);
    else lqg_step(d, s, k, m, limit, tau, next);
}

/* The index outputs of the torques of trajectory sample k from measurements carrying `index` (of the trajectory's
   samples), by a law predicting over `assumed`; tau_index names the master's sample. */
static void index_outputs(Instance *inst, long long k, double index, int assumed, double out[4])
{
    const LqgData *d = inst->data;
    const FmuState *st = inst->state;
    out[0] = loop_index_of_time(((double)k + st->start) * d->dt);
    out[1] = loop_measured_delay((double)k, index);
    out[2] = (double)assumed;
    out[3] = loop_index_of_time(st->start * d->dt);
}

/* d > 0: run sample committed.k from the measurements m carrying `index` and hold its torques. Before sample d
   there is no measurement (y_d(0)); m NULL or a master's placeholder is none either (y_d of the plant's sample). */
static void delayed_sample(Instance *inst, const double *m_present, double index)
{
    LqgData *d = inst->data;
    FmuState *st = inst->state;
    const double limit[2] = {VALUE(inst, IDX_tau1_max), VALUE(inst, IDX_tau2_max)};
    const long long k = st->committed.k;
    const double *m = m_present;
    if (k < d->delay) m = d->desired, index = LOOP_NO_SAMPLE; /* no measurement before t = 0: y_d(0) */
    else if (m == NULL || loop_is_placeholder(index, m, N_MEAS))
        m = d->desired + lqg_clamp(d, k - d->delay) * N_MEAS, index = LOOP_NO_SAMPLE;
    LqgState next;
    law_step(d, &st->committed, k, m, limit, st->held, &next);
    st->committed = next;
    index_outputs(inst, k, index, d->delay, st->held_index);
    lqg_set_outputs(inst, st->held, st->held_index);
}

static fmi2Status lqg_sample(Instance *inst)
{
    LqgData *d = inst->data;
    FmuState *st = inst->state;
    fmi2Status status = configure(inst);
    if (status != fmi2OK) return status;
    if (d->delay > 0) { /* no feedthrough: the torques held since the last step */
        lqg_set_outputs(inst, st->held, st->held_index);
        return fmi2OK;
    }
    double t = inst->time;
    if (!isfinite(t) || t < -0.5 * d->dt) {
        glue_log(inst, fmi2Error, "evaluating the outputs at t = %.17g s: t: must be a finite time >= 0 s", t);
        return fmi2Error;
    }
    double k = nearbyint(t / d->dt) - st->start; /* the trajectory's sample */
    if (k != (double)st->committed.k) {
        glue_log(inst, fmi2Error, "evaluating the outputs at t = %.17g s: k: the controller is at sample %lld, got "
                 "sample %.0f (one call per sample; controller_lqg starts at t = 0)", t, st->committed.k, k);
        return fmi2Error;
    }
    double m[N_MEAS], tau[2], out[4];
    const double limit[2] = {VALUE(inst, IDX_tau1_max), VALUE(inst, IDX_tau2_max)};
    lqg_measurements(inst, m);
    const double index = loop_trajectory_index(VALUE(inst, IDX_sample_index_m), st->start);
    /* fmpy's first step: no sample yet, not a measurement of q = 0; automatic, an index naming an earlier sample (a
       Jacobi master's first steps, before fmi2DoStep switches to the measured delay): no measurement of sample k (an
       explicit 0 is honoured: the law it names runs on what it gets, and the FMU warns); such inputs are those of an
       earlier communication point, so the plant's report of the torque it held is no report on sample k - 1 either */
    const int earlier = VALUE(inst, IDX_loop_delay_samples) == LOOP_AUTOMATIC && loop_measured_delay(k, index) >= 1.0;
    const int stale = loop_is_placeholder(index, m, N_MEAS) || earlier;
    const double *used = stale ? d->desired + lqg_clamp(d, (long long)k) * N_MEAS : m;
    LqgState base = st->committed;
    double applied[2];
    if (!stale && lqg_plant_applied(inst, (long long)k, 0, applied))
        lqg_with_applied(d, &base, (long long)k - 1, applied);
    law_step(d, &base, (long long)k, used, limit, tau, &st->pending);
    index_outputs(inst, (long long)k, index, 0, out);
    lqg_set_outputs(inst, tau, out);
    return fmi2OK;
}

static fmi2Status lqg_initialize(Instance *inst)
{
    FmuState *st = inst->state;
    LqgData *d = inst->data;
    fmi2Status status = configure(inst);
    if (status != fmi2OK) return status;
    free(d->correction), d->correction = NULL, d->n_correction = 0;
    status = learned_ff_load(inst, TRAJECTORY_SHA256, PARAMETER_SHA256, &d->correction, &d->n_correction);
    if (status != fmi2OK) return status;
    memset(st, 0, sizeof *st); /* on the trajectory, nothing sent, integrators empty; automatic: delay 0 */
    status = configure(inst);
    if (status != fmi2OK) return status;
    if (d->use_bank) bank_initial_state(&d->bank, &st->committed);
    if (d->delay == 0) return lqg_sample(inst);
    if (nearbyint(inst->time / d->dt) != 0.0) {
        glue_log(inst, fmi2Error, "fmi2ExitInitializationMode: start time %.17g s: controller_lqg starts at t = 0 "
                 "(sample 0 of the trajectory)", inst->time);
        return fmi2Error;
    }
    delayed_sample(inst, NULL, LOOP_NO_SAMPLE); /* sample 0, from the parameters and the trajectory alone */
    return fmi2OK;
}

static const char *setting(Instance *inst)
{
    return VALUE(inst, IDX_loop_delay_samples) == LOOP_AUTOMATIC ? " (automatic)" : "";
}

/* A measured delay at fmi2DoStep that contradicts the law's: said once per run (as the Python FMU's warn_delay). */
static void warn_delay(Instance *inst, double t, double measured, int assumed)
{
    FmuState *st = inst->state;
    if (measured < 0.0 || measured == (double)assumed || st->delay_contradictions++ > 0) return;
    glue_log(inst, fmi2Warning, "loop delay contradiction at t = %.17g s: the measurements present at fmi2DoStep are "
             "of the plant's sample %g sample(s) before the one the torques are for (tau_index - sample_index_m), "
             "but the law predicts over %d (loop_delay_samples = %g%s); the master's stepping differs from the one "
             "the law is set for (a Jacobi master reads the torques before it sets the measurements). Use "
             "loop_delay_samples = -1 (automatic), which measures the delay and predicts over it", t, measured,
             assumed, VALUE(inst, IDX_loop_delay_samples), setting(inst));
}

/* Measurements without an index that are no master's placeholder: the index is not wired (said once). */
static void warn_unwired(Instance *inst, double t, double index, const double m[N_MEAS])
{
    FmuState *st = inst->state;
    double j;
    if (st->unwired_warned || loop_received_index(index, &j) || loop_is_placeholder(index, m, N_MEAS)) return;
    st->unwired_warned = 1;
    glue_log(inst, fmi2Warning, "sample_index_m is %.17g at t = %.17g s while the measurements are not a master's "
             "placeholder: the sample index is not wired (connect the plant's sample_index to the sensors and the "
             "sensors' sample_index_m to this FMU, or the plant's sample_index here directly), so the loop delay "
             "cannot be measured; loop_delay_samples = %g%s is taken as given (automatic: 0, a Gauss-Seidel "
             "master's)", index, t, VALUE(inst, IDX_loop_delay_samples), setting(inst));
}

/* Automatic delay (flexarm_controller_lqg_fmu._switch): from fmi2DoStep(t_k) on, predict over `delay` without
   feedthrough, as loop_delay_samples = delay would; samples 0 .. k again from the trajectory alone, then
   k + 1 .. k + n from the inputs present. */
static void switch_delay(Instance *inst, double t, long long k, int delay, double n, const double m[N_MEAS],
                         double index)
{
    LqgData *d = inst->data;
    FmuState *st = inst->state;
    st->delay = delay;
    st->switch_end = k + 1;
    configure(inst); /* the same parameters, now with the delay: cannot fail where it succeeded before */
    glue_log(inst, fmi2OK, "loop_delay_samples = -1 (automatic): the loop delay measured at fmi2DoStep(t = %.17g s) "
             "is %d samples (the master reads the torques before it sets the measurements); predicting over %d "
             "samples from sample %lld on", t, delay, delay, k + 1);
    memset(&st->committed, 0, sizeof st->committed);
    memset(&st->pending, 0, sizeof st->pending);
    if (d->use_bank) bank_initial_state(&d->bank, &st->committed);
    for (long long s = 0; s <= k; s++) {
        delayed_sample(inst, NULL, LOOP_NO_SAMPLE);
        for (int i = 0; i < st->n_foreign; i++) /* the torque the plant held over s (fmpy's fill, the old law's) */
            if (st->foreign[i][0] == (double)s) lqg_with_applied(d, &st->committed, s, &st->foreign[i][1]);
    }
    for (double i = 0; i < n; i++) delayed_sample(inst, m, index);
}

static fmi2Status lqg_do_step(Instance *inst, double t, double h)
{
    LqgData *d = inst->data;
    FmuState *st = inst->state;
    double n;
    if (glue_whole_samples(h, d->dt, &n)) {
        glue_log(inst, fmi2Error, "fmi2DoStep: step_size: %.17g s at t = %.17g s is not a whole multiple of the "
                 "controller's 1 ms sample (allowed: n * %g s within %g s, n = 0, 1, 2, ...; controller_lqg is a "
                 "sampled filter and runs the samples inside a longer step with its inputs held)", h, t, d->dt,
                 GLUE_STEP_TOLERANCE);
        return fmi2Error;
    }
    if (n == 0) return fmi2OK; /* no sample instant in the step: nothing changes */
    double m[N_MEAS];
    lqg_measurements(inst, m); /* present at fmi2DoStep, held in the step */
    if (lqg_starts_late(inst, t, d->dt, &st->start)) {
        if (d->delay > 0) /* sample 0's torques, held since initialisation, now run at the next sample */
            index_outputs(inst, 0, LOOP_NO_SAMPLE, d->delay, st->held_index), lqg_set_outputs(inst, st->held,
                                                                                             st->held_index);
        return fmi2OK; /* no sample of the slew in this step */
    }
    const double kt = nearbyint(t / d->dt) - st->start; /* the trajectory's sample at t */
    const double index = loop_trajectory_index(VALUE(inst, IDX_sample_index_m), st->start);
    warn_unwired(inst, t, index, m);
    double applied[2];
    /* automatic: the torques held over the samples up to the switch were the law's before it (its own reports too) */
    const int before_switch = VALUE(inst, IDX_loop_delay_samples) == LOOP_AUTOMATIC
                              && (d->delay == 0 || kt <= (double)st->switch_end);
    const int foreign = lqg_plant_applied(inst, (long long)kt, before_switch, applied);
    if (foreign) lqg_remember(st->foreign, &st->n_foreign, (long long)kt - 1, applied);
    if (d->delay > 0) {
        if (kt + 1 != (double)st->committed.k) {
            glue_log(inst, fmi2Error, "fmi2DoStep: current_time: %.17g s is sample %.0f, but the controller computed "
                     "sample %lld last (one fmi2DoStep per communication point, from t = 0)", t, kt,
                     st->committed.k - 1);
            return fmi2Error;
        }
        if (foreign) lqg_with_applied(d, &st->committed, (long long)kt - 1, applied);
        for (double i = 0; i < n; i++) delayed_sample(inst, m, index);
        warn_delay(inst, t, st->held_index[1], d->delay);
        return fmi2OK;
    }
    const double k = kt, measured = loop_measured_delay(k, index);
    if (VALUE(inst, IDX_loop_delay_samples) == LOOP_AUTOMATIC && measured >= 1.0) {
        /* the master sets the measurements after it reads the torques: predict over the measured delay */
        /* the torques published after this step of n samples are measured + n samples late (2n in a Jacobi
           master at n ms) */
        switch_delay(inst, t, (long long)k, measured + n < MAX_DELAY ? (int)(measured + n) : MAX_DELAY, n, m, index);
        return fmi2OK;
    }
    warn_delay(inst, t, measured, 0);
    st->committed = st->pending; /* sample k, from the inputs present (the glue sampled them before this call) */
    if (n > 1) { /* the samples inside the step, of the inputs held since t (their torques are not published) */
        double tau[2];
        const double limit[2] = {VALUE(inst, IDX_tau1_max), VALUE(inst, IDX_tau2_max)};
        for (double i = 1; i < n; i++) {
            LqgState next;
            law_step(d, &st->committed, st->committed.k, m, limit, tau, &next);
            st->committed = next;
        }
    }
    return fmi2OK;
}

const ModelInfo MODEL_INFO = {
    MODEL_IDENTIFIER_STRING, MODEL_GUID_STRING, MODEL_VARS, MODEL_N_VARS, MODEL_RESOURCES, MODEL_N_RESOURCES,
    sizeof(FmuState), lqg_load, lqg_unload, lqg_initialize, lqg_sample, lqg_do_step, ON_DEMAND,
};
