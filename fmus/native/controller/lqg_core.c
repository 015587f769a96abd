/*
 * The LQG's Kalman filter and predictor, shared by controller_lqg.c (the LQG FMU) and controller.c (the paper's
 * laws predicting over a measured loop delay, flexarm.lqg.PredictedTracking): resource reading, which sample and
 * design point each step of the estimate (steps 1-3 of controller_lqg.c's header) uses, and the transient filter
 * gains. The arithmetic of each step, and of the gains' time-varying filter, is flexarm/filter_law.py's, generated
 * (control_law_api.h).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "control_law_api.h"
#include "controller_lqg.h"
#include "loop_index.h"
#include "model_vars.h"

double *lqg_read_array(Instance *inst, const char *file, const char *text, const char *name, size_t n)
{
    double *out = malloc(n * sizeof *out);
    if (out == NULL) glue_log(inst, fmi2Error, "resources/%s: out of memory for '%s'", file, name);
    else if (glue_read_doubles(inst, file, text, name, out, n)) free(out), out = NULL;
    return out;
}

void lqg_free_design(Design *g)
{
    free(g->times), free(g->phi), free(g->gamma), free(g->m), free(g->k), free(g->k_integral);
    memset(g, 0, sizeof *g);
}

int lqg_read_design(Instance *inst, const char *file, const char *text, Design *g, double *c)
{
    double count;
    if (glue_read_doubles(inst, file, text, "count", &count, 1) || glue_read_doubles(inst, file, text, "C", c,
                                                                                       N_MEAS * N_STATE))
        return -1;
    size_t n = (size_t)count;
    g->count = (int)count;
    g->times = lqg_read_array(inst, file, text, "times", n);
    g->phi = lqg_read_array(inst, file, text, "Phi", n * N_STATE * N_STATE);
    g->gamma = lqg_read_array(inst, file, text, "Gamma", n * N_STATE * 2);
    g->m = lqg_read_array(inst, file, text, "M", n * N_STATE * N_MEAS);
    g->k = lqg_read_array(inst, file, text, "K", n * N_WEIGHTS * 2 * N_STATE);
    g->k_integral = lqg_read_array(inst, file, text, "K_integral", n * N_WEIGHTS * 2 * N_AUG);
    if (!(g->times && g->phi && g->gamma && g->m && g->k && g->k_integral)) return -1;
    if (lqg_split_integral_gain(g->k_integral, n * N_WEIGHTS * 2)) {
        glue_log(inst, fmi2Error, "resources/%s: out of memory for 'K_integral'", file);
        return -1;
    }
    g->k_xi = g->k_integral + n * N_WEIGHTS * 2 * N_STATE;
    return 0;
}

int lqg_split_integral_gain(double *k_integral, size_t rows)
{
    double *k_xi = malloc(rows * 2 * sizeof *k_xi);
    if (k_xi == NULL) return -1;
    for (size_t r = 0; r < rows; r++) { /* row r's K block moves down to r * 22, before row r + 1 starts */
        k_xi[2 * r] = k_integral[r * N_AUG + N_STATE], k_xi[2 * r + 1] = k_integral[r * N_AUG + N_STATE + 1];
        memmove(k_integral + r * N_STATE, k_integral + r * N_AUG, N_STATE * sizeof *k_integral);
    }
    memcpy(k_integral + rows * N_STATE, k_xi, rows * 2 * sizeof *k_xi);
    free(k_xi);
    return 0;
}

/* -- the law -------------------------------------------------------------------------------------------------- */
/* x <- Phi x + Gamma du + drift at design point i (flexarm.filter_law.time_update, generated); drift NULL: none
   (a zero drift, which changes no bit: law_time_update_drift's sums are never -0.0). */
void lqg_propagate(const Design *g, int i, double *x, const double du[2], const double *drift)
{
    static const double no_drift[N_STATE];
    double next[N_STATE];
    law_time_update_drift(g->phi + (size_t)i * N_STATE * N_STATE, g->gamma + (size_t)i * N_STATE * 2, x, du,
                          drift != NULL ? drift : no_drift, next);
    memcpy(x, next, sizeof next);
}

void lqg_feedforward(const LqgData *d, long long k, double nominal[2], double command[2])
{
    const double *slew = k < d->n_steps ? d->feedforward + 2 * k : NULL; /* zero feedforward in the hold */
    const double none[2] = {0.0, 0.0}, *correction = k < d->n_correction ? d->correction + 2 * k : none;
    for (int r = 0; r < 2; r++) nominal[r] = slew ? slew[r] : 0.0;
    law_corrected_feedforward(nominal, correction, command); /* flexarm.control_law.corrected_feedforward */
}

/* Steps 1-3 of the law (controller_lqg.c's header): the posterior at j = max(k - d, 0) from measurements m of
   sample j and the state s after sample k - 1, and the error predicted to sample k with the torques sent. */
void lqg_estimate(const LqgData *d, const LqgState *s, long long k, const double m[N_MEAS], double x_post[N_STATE],
                  double x_now[N_STATE])
{
    const Design *g = d->design;
    const int dl = d->delay;
    long long j = k - dl > 0 ? k - dl : 0;
    double x[N_STATE];
    memcpy(x, s->x_post[0], sizeof x);
    if (s->started && j > 0 && k - dl >= 0) lqg_propagate(g, d->index[lqg_clamp(d, j - 1)], x, s->du[0], NULL); /* 1 */
    const double *y_d = d->desired + lqg_clamp(d, j) * N_MEAS;                                            /* 2 */
    const double *gain = d->gains != NULL && j < d->n_gains ? d->gains + (size_t)j * N_STATE * N_MEAS
                                                             : g->m + (size_t)d->index[lqg_clamp(d, j)] * N_STATE * N_MEAS;
    double e[N_MEAS]; /* flexarm.filter_law.corrected */
    law_innovation(x, d->c, m, y_d, e);
    law_updated(x, gain, e, x_post);
    memcpy(x_now, x_post, N_STATE * sizeof *x_now); /* 3: the torques of samples j .. k - 1 */
    int first = k - dl >= 0 ? 1 : (int)(dl + 1 - k);
    for (int row = first, n = 0; row <= dl; row++, n++)
        lqg_propagate(g, d->index[lqg_clamp(d, j + n)], x_now, s->du[row], NULL);
}

void lqg_schedule_index(const double *times, int count, int n_steps, double dt, int *index)
{
    int i = 0; /* times ascending: the set in force only moves on (flexarm.gain_schedule.schedule_index) */
    for (int k = 0; k <= n_steps; k++) {
        const double t = k * dt;
        double switched = 1.0;
        while (i + 1 < count && (law_has_switched(&times[i + 1], &t, &switched), switched != 0.0)) i++;
        index[k] = i;
    }
}

/* The plant's report of the torque it held over sample k - 1: 1 and the torque when it was not this law's
   (tau_lag != 0) or, with `any_lag` (up to a switch to the measured delay), whatever tau_lag says: the law before
   the switch used those samples' measurements, the law after it has none for them. An unwired tau_lag holds 0
   and unwired torques 0: nothing to correct, nothing to remember. */
int lqg_plant_applied(Instance *inst, long long k, int any_lag, double torque[2])
{
    if (k < 1) return 0;
    torque[0] = VALUE(inst, IDX_tau1_applied), torque[1] = VALUE(inst, IDX_tau2_applied);
    if (VALUE(inst, IDX_tau_lag) != 0.0) return 1;
    return any_lag && (torque[0] != 0.0 || torque[1] != 0.0);
}

/* The torque deviation the filter of state s assumes for `sample` replaced by the plant's `torque`. */
void lqg_with_applied(const LqgData *d, LqgState *s, long long sample, const double torque[2])
{
    const long long row = d->delay - (s->k - 1 - sample); /* du rows 0 .. d: samples s->k - 1 - d .. s->k - 1 */
    if (row < 0 || row > d->delay) return;
    double nominal[2], command[2];
    lqg_feedforward(d, sample, nominal, command);
    s->du[row][0] = torque[0] - nominal[0], s->du[row][1] = torque[1] - nominal[1];
}

void lqg_set_outputs(Instance *inst, const double tau[2], const double index[4])
{
    VALUE(inst, IDX_tau1) = tau[0];
    VALUE(inst, IDX_tau2) = tau[1];
    VALUE(inst, IDX_tau_index) = index[0];
    VALUE(inst, IDX_loop_delay) = index[1];
    VALUE(inst, IDX_loop_delay_assumed) = index[2];
    VALUE(inst, IDX_slew_start_index) = index[3];
}

void lqg_measurements(Instance *inst, double m[N_MEAS])
{
    static const int vr[N_MEAS] = {IDX_q1_m, IDX_q2_m, IDX_qd1_m, IDX_qd2_m, IDX_eps1_m,
                                   IDX_eps2_m, IDX_eps3_m, IDX_eps4_m, IDX_eps5_m, IDX_eps6_m};
    for (int j = 0; j < N_MEAS; j++) m[j] = VALUE(inst, vr[j]);
}

int lqg_starts_late(Instance *inst, double t, double dt, double *start)
{
    /* (the only fmi2DoStep at t = 0 is the first, or one from a state saved before it) */
    if (inst->outputs_read || nearbyint(t / dt) != 0.0) return 0;
    double m[N_MEAS];
    lqg_measurements(inst, m);
    if (!loop_is_placeholder(VALUE(inst, IDX_sample_index_m), m, N_MEAS)) return 0;
    *start = 1.0;
    glue_log(inst, fmi2OK, "the master exchanged nothing before its first step (no output read, its placeholder at "
             "the inputs of fmi2DoStep(t = %.17g s): no torque of this FMU reached the plant over it); the slew starts "
             "one sample later, at t = %.17g s (slew_start_index = 2)", t, dt);
    return 1;
}

/* Keep (sample, torque) in the last LQG_N_FOREIGN reports (`*n` of them so far, oldest dropped). */
void lqg_remember(double foreign[][3], int *n, long long sample, const double torque[2])
{
    if (*n == LQG_N_FOREIGN) {
        memmove(foreign[0], foreign[1], (LQG_N_FOREIGN - 1) * sizeof foreign[0]);
        (*n)--;
    }
    foreign[*n][0] = (double)sample, foreign[*n][1] = torque[0], foreign[*n][2] = torque[1];
    (*n)++;
}

/* -- the time-varying filter of the predicting law ------------------------------------------------------------ */
int lqg_read_noise(Instance *inst, const char *file, const char *text, int count, Noise *noise)
{
    noise->w = lqg_read_array(inst, file, text, "W", (size_t)count * N_STATE * N_STATE);
    if (noise->w == NULL || glue_read_doubles(inst, file, text, "V", noise->v, N_MEAS * N_MEAS) ||
        glue_read_doubles(inst, file, text, "P_prior0", noise->p_prior0, N_STATE * N_STATE))
        return -1;
    return 0;
}

int lqg_transient_gains(Instance *inst, LqgData *d, const Noise *noise, double factor)
{
    const long n = d->n_steps;
    lqg_free_gains(d);
    d->gains = malloc((size_t)n * N_STATE * N_MEAS * sizeof *d->gains);
    d->gains_p = malloc(N_STATE * N_STATE * sizeof *d->gains_p);
    if (d->gains == NULL || d->gains_p == NULL) {
        lqg_free_gains(d);
        glue_log(inst, fmi2Error, "the predictor's filter gains: out of memory");
        return -1;
    }
    for (int i = 0; i < N_STATE * N_STATE; i++) d->gains_p[i] = factor * noise->p_prior0[i];
    d->n_gains = n, d->gains_made = 0, d->gains_noise = noise;
    return 0;
}

int lqg_gains_through(Instance *inst, LqgData *d, long long k)
{
    if (d->gains == NULL) return 0;
    const long last = k < d->n_gains - 1 ? (long)k : d->n_gains - 1;
    double p_next[N_STATE * N_STATE];
    for (long j = d->gains_made; j <= last; j++) { /* flexarm.lqg_design.transient_gains: the generated step */
        const size_t i = (size_t)d->index[j];
        double *gain = d->gains + (size_t)j * N_STATE * N_MEAS;
        law_covariance_step(d->gains_p, d->c, d->gains_noise->v, d->design->phi + i * N_STATE * N_STATE,
                            d->gains_noise->w + i * N_STATE * N_STATE, gain, p_next);
        for (int q = 0; q < N_STATE * N_MEAS; q++)
            if (!isfinite(gain[q])) {
                glue_log(inst, fmi2Error, "the predictor's filter: its gain at sample %ld is not finite (the "
                         "innovation covariance is singular, or the covariance recursion diverged)", j);
                return -1; /* gains_made stays: the next call fails alike */
            }
        memcpy(d->gains_p, p_next, sizeof p_next);
        d->gains_made = j + 1;
    }
    return 0;
}

void lqg_free_gains(LqgData *d)
{
    free(d->gains), free(d->gains_p);
    d->gains = d->gains_p = NULL, d->n_gains = d->gains_made = 0, d->gains_noise = NULL;
}
