/*
 * Native controller FMUs: flexarm.control.TrackingController in C, one source for every variant.
 *
 *     tau = sat( tau_ff(t_k) - K(t_k) (x_hat - x_hat_d(t_k)) ),  x_hat = E m
 *
 * m = (q1, q2, qd1, qd2, eps1..eps6) measured; E the rigid-bracket reconstruction (eqs. 21-31) with the
 * chosen theta7-rate estimate; x_hat_d = E m_d from the desired measurements; K the reduced gain of the
 * schedule's set in force (index: the last switching time <= t_k + 1e-9). As the library, the law is
 * evaluated as tau_ff - (K E) m + K x_hat_d with K E and K x_hat_d precomputed. After the slew
 * (k >= n_steps) it holds the final desired state with zero feedforward and the last gains.
 *
 * controller_mode.h (generated per FMU) fixes the variant: CONTROLLER_FEEDFORWARD, CONTROLLER_FEEDBACK
 * (0/1) and the gains resource (continuous or discrete-time designs). Trajectory, estimators and gains are
 * resources (SHA-256 checked).
 *
 * A learned feedforward correction (flexarm.ilc) is read at initialisation from the String parameter
 * feedforward_correction_file (learned_ff.c; checked against TRAJECTORY_SHA256 and PARAMETER_SHA256 of
 * learned_ff_data.h, the files this FMU was built from). Row k is added to the feedforward of sample k (k < m).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "controller_mode.h"
#include "fmi2_glue.h"
#include "learned_ff.h"
#include "learned_ff_data.h"
#include "loop_index.h"
#include "model_vars.h"

#define N_MEAS 10
#define N_STATE 22
#define N_SETS 4
static const char *const SCHEDULE_LABELS[3] = {"200ms", "20ms", "single"};
static const double SCHEDULE_PERIODS[3] = {0.2, 0.02, 0.0};

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
    Schedule schedules[N_SETS][3];
    /* derived for the configuration `key` */
    double key[5];
    int *gain_index;      /* n_steps + 1 */
    double *gain_per_meas; /* count x 2 x 10 */
    double *offsets;      /* (n_steps + 1) x 2 */
    double *correction;   /* n_correction x 2: the learned feedforward correction (NULL: none) */
    long n_correction;
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

static void controller_unload(Instance *inst)
{
    ControllerData *d = inst->data;
    if (d == NULL) return;
    free(d->feedforward), free(d->desired), free(d->gain_index), free(d->gain_per_meas), free(d->offsets);
    free(d->correction);
    for (int i = 0; i < N_SETS; i++)
        for (int s = 0; s < 3; s++) free(d->schedules[i][s].times), free(d->schedules[i][s].gains);
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
        for (int s = 0; s < 3; s++)
            if (read_schedule(inst, MODEL_INFO.resources[gains].file, contents[gains], i + 1, s, &d->schedules[i][s]))
                goto fail;
#else
    (void)read_schedule;
#endif
    d->key[0] = -1;
    return 0;
fail:
    controller_unload(inst);
    return -1;
}

/* Read feedforward_correction_file into d->correction ("" : none); fmi2Error naming the file and the reason. */
static fmi2Status load_correction(Instance *inst)
{
    ControllerData *d = inst->data;
    free(d->correction), d->correction = NULL, d->n_correction = 0;
    const char *path = glue_string(inst, IDX_feedforward_correction_file);
    if (path[0] == '\0') return fmi2OK;
    if (!CONTROLLER_FEEDFORWARD) {
        glue_log(inst, fmi2Error, "feedforward_correction_file: this controller has no feedforward to correct");
        return fmi2Error;
    }
    return learned_ff_load(inst, path, TRAJECTORY_SHA256, PARAMETER_SHA256, &d->correction, &d->n_correction);
}

static int schedule_of(double period)
{
    for (int s = 0; s < 3; s++)
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
    const double *est = d->estimator[(int)key[2] - 1];
    free(d->gain_per_meas);
    d->gain_per_meas = malloc((size_t)sch->count * 2 * N_MEAS * sizeof(double));
    if (d->gain_per_meas == NULL) return fmi2Error;
    for (int g = 0; g < sch->count; g++) /* K E */
        for (int i = 0; i < 2; i++)
            for (int j = 0; j < N_MEAS; j++) {
                double acc = 0.0;
                for (int r = 0; r < N_STATE; r++) acc += sch->gains[(g * 2 + i) * N_STATE + r] * est[r * N_MEAS + j];
                d->gain_per_meas[(g * 2 + i) * N_MEAS + j] = acc;
            }
    for (int k = 0; k <= d->n_steps; k++) {
        double t = k * d->dt + 1e-9; /* GainSchedule.index_at: the last switching time <= t */
        int g = 0;
        while (g + 1 < sch->count && sch->times[g + 1] <= t) g++;
        d->gain_index[k] = g;
        double xd[N_STATE]; /* x_hat_d = E m_d */
        for (int r = 0; r < N_STATE; r++) {
            double acc = 0.0;
            for (int j = 0; j < N_MEAS; j++) acc += d->desired[k * N_MEAS + j] * est[r * N_MEAS + j];
            xd[r] = acc;
        }
        for (int i = 0; i < 2; i++) {
            double acc = 0.0;
            for (int r = 0; r < N_STATE; r++) acc += sch->gains[(g * 2 + i) * N_STATE + r] * xd[r];
            d->offsets[k * 2 + i] = acc;
        }
    }
#endif
    memcpy(d->key, key, sizeof key);
    return fmi2OK;
}

static fmi2Status controller_sample(Instance *inst)
{
    ControllerData *d = inst->data;
    fmi2Status status = configure(inst);
    if (status != fmi2OK) return status;
    long k = lround(inst->time / d->dt);
    if (k < 0) k = 0;
    int kc = k < d->n_steps ? (int)k : d->n_steps;
    double tau[2] = {0.0, 0.0};
#if CONTROLLER_FEEDFORWARD
    if (k < d->n_steps) tau[0] = d->feedforward[2 * k], tau[1] = d->feedforward[2 * k + 1];
    if (k < d->n_correction) tau[0] += d->correction[2 * k], tau[1] += d->correction[2 * k + 1];
#endif
#if CONTROLLER_FEEDBACK
    static const int MEAS[N_MEAS] = {IDX_q1_m, IDX_q2_m, IDX_qd1_m, IDX_qd2_m, IDX_eps1_m,
                                     IDX_eps2_m, IDX_eps3_m, IDX_eps4_m, IDX_eps5_m, IDX_eps6_m};
    const double *ke = d->gain_per_meas + (size_t)d->gain_index[kc] * 2 * N_MEAS;
    for (int i = 0; i < 2; i++) {
        double acc = 0.0;
        for (int j = 0; j < N_MEAS; j++) acc += ke[i * N_MEAS + j] * VALUE(inst, MEAS[j]);
        tau[i] -= acc - d->offsets[kc * 2 + i];
    }
#else
    (void)kc;
#endif
    const double limit[2] = {VALUE(inst, IDX_tau1_max), VALUE(inst, IDX_tau2_max)};
    for (int i = 0; i < 2; i++) tau[i] = fmin(fmax(tau[i], -limit[i]), limit[i]);
    VALUE(inst, IDX_tau1) = tau[0];
    VALUE(inst, IDX_tau2) = tau[1];
    VALUE(inst, IDX_tau_index) = loop_index_of_time((double)k * d->dt); /* the torques' sample */
    VALUE(inst, IDX_loop_delay) = loop_measured_delay((double)k, VALUE(inst, IDX_sample_index_m));
    VALUE(inst, IDX_loop_delay_assumed) = 0.0; /* the paper's law predicts over no delay */
    return fmi2OK;
}

typedef struct { /* the FMU state: only what the log says once per run */
    int delay_contradictions;
} ControllerState;

static fmi2Status controller_initialize(Instance *inst)
{
    ((ControllerState *)inst->state)->delay_contradictions = 0;
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
    /* the outputs were just sampled from the inputs present at fmi2DoStep: a delay there contradicts the law's
       (flexarm_controller_base.ControllerSlave.warn_delay); said once per run */
    ControllerState *st = inst->state;
    const double measured = VALUE(inst, IDX_loop_delay);
    if (measured >= 0.0 && measured != 0.0 && st->delay_contradictions++ == 0)
        glue_log(inst, fmi2Warning, "loop delay contradiction at t = %.17g s: the measurements present at "
                 "fmi2DoStep are of the plant's sample %g sample(s) before the one the torques are for (tau_index - "
                 "sample_index_m), but the law predicts over 0 (the paper's law assumes no delay); the master's "
                 "stepping differs from the one the law is set for (a Jacobi master reads the torques before it sets "
                 "the measurements). Use controller_lqg with loop_delay_samples = -1 (automatic), which measures the "
                 "delay and predicts over it", t, measured);
    return fmi2OK; /* the torque is a function of the time and the inputs */
}

const ModelInfo MODEL_INFO = {
    MODEL_IDENTIFIER_STRING, MODEL_GUID_STRING, MODEL_VARS, MODEL_N_VARS, MODEL_RESOURCES, MODEL_N_RESOURCES,
    sizeof(ControllerState), controller_load, controller_unload, controller_initialize, controller_sample,
    controller_do_step,
};
