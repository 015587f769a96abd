/*
 * The LQG's Kalman filter and predictor, shared by controller_lqg.c (the LQG FMU) and controller.c (the paper's
 * laws predicting over a measured loop delay, flexarm.lqg.PredictedTracking): resource reading, which sample and
 * design point each step of the estimate (steps 1-3 of controller_lqg.c's header) uses, and the transient filter
 * gains. The arithmetic of each step is flexarm/filter_law.py's, generated (control_law_api.h); the compensated
 * matrix-vector product here serves the payload bank and the gains' design, still written in C.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "control_law_api.h"
#include "controller_lqg.h"
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
    return g->times && g->phi && g->gamma && g->m && g->k && g->k_integral ? 0 : -1;
}

/* -- the law -------------------------------------------------------------------------------------------------- */
/* y = A x for A (rows x cols, row stride `stride`), for what is not generated yet (the bank's drift at
   instantiation, the predictor's filter gains): the compensated sums of the generated law
   (flexarm.law_ops.mat_vec, whose docstring says why), the same bits. */
/* sum += term, carry += the exact rounding error of that addition (Knuth's TwoSum: no branch; the error is the
   one Neumaier's test-and-subtract gives, bit for bit, both being exact). */
#define NEUMAIER(sum, carry, term)                                         \
    do {                                                                   \
        const double t_ = (sum) + (term), b_ = t_ - (sum);                 \
        (carry) += ((sum) - (t_ - b_)) + ((term) - b_);                    \
        (sum) = t_;                                                        \
    } while (0)

void lqg_mat_vec(const double *a, int rows, int cols, int stride, const double *x, double *y)
{
    int r = 0;
    for (; r + 4 <= rows; r += 4) { /* four rows at a time: four independent chains (the same sums, faster) */
        const double *a0 = a + r * stride, *a1 = a0 + stride, *a2 = a1 + stride, *a3 = a2 + stride;
        double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0, c0 = 0.0, c1 = 0.0, c2 = 0.0, c3 = 0.0;
        for (int c = 0; c < cols; c++) {
            const double t0 = a0[c] * x[c], t1 = a1[c] * x[c], t2 = a2[c] * x[c], t3 = a3[c] * x[c];
            NEUMAIER(s0, c0, t0);
            NEUMAIER(s1, c1, t1);
            NEUMAIER(s2, c2, t2);
            NEUMAIER(s3, c3, t3);
        }
        y[r] = s0 + c0, y[r + 1] = s1 + c1, y[r + 2] = s2 + c2, y[r + 3] = s3 + c3;
    }
    for (; r < rows; r++) {
        double sum = 0.0, carry = 0.0;
        for (int c = 0; c < cols; c++) {
            const double term = a[r * stride + c] * x[c];
            NEUMAIER(sum, carry, term);
        }
        y[r] = sum + carry;
    }
}

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
    for (int r = 0; r < 2; r++) {
        nominal[r] = slew ? slew[r] : 0.0;
        command[r] = nominal[r] + (k < d->n_correction ? d->correction[2 * k + r] : 0.0);
    }
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

/* Keep (sample, torque) in the last LQG_N_FOREIGN reports (`*n` of them so far, oldest dropped). */
void lqg_set_outputs(Instance *inst, const double tau[2], const double index[3])
{
    VALUE(inst, IDX_tau1) = tau[0];
    VALUE(inst, IDX_tau2) = tau[1];
    VALUE(inst, IDX_tau_index) = index[0];
    VALUE(inst, IDX_loop_delay) = index[1];
    VALUE(inst, IDX_loop_delay_assumed) = index[2];
}

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

/* c = a b for a (n x m), b (m x p), all row-major; compensated sums as lqg_mat_vec. */
static void mat_mul(const double *a, const double *b, int n, int m, int p, double *c)
{
    for (int i = 0; i < n; i++)
        for (int j = 0; j < p; j++) {
            double sum = 0.0, carry = 0.0;
            for (int r = 0; r < m; r++) NEUMAIER(sum, carry, a[i * m + r] * b[r * p + j]);
            c[i * p + j] = sum + carry;
        }
}

int lqg_transient_gains(Instance *inst, LqgData *d, const Noise *noise, double factor)
{
    const Design *g = d->design;
    const long n = d->n_steps;
    double *gains = malloc((size_t)n * N_STATE * N_MEAS * sizeof *gains);
    double *p = malloc(5 * N_STATE * N_STATE * sizeof *p);
    if (gains == NULL || p == NULL) {
        free(gains), free(p);
        glue_log(inst, fmi2Error, "the predictor's filter gains: out of memory");
        return -1;
    }
    double *a = p + N_STATE * N_STATE, *b = a + N_STATE * N_STATE, *phi_t = b + N_STATE * N_STATE;
    double *ct = phi_t + N_STATE * N_STATE; /* C^T, 22 x 10 */
    double cp[N_MEAS * N_STATE], s[N_MEAS * N_MEAS];
    for (int i = 0; i < N_STATE * N_STATE; i++) p[i] = factor * noise->p_prior0[i];
    for (int r = 0; r < N_STATE; r++)
        for (int q = 0; q < N_MEAS; q++) ct[r * N_MEAS + q] = d->c[q * N_STATE + r];
    for (long j = 0; j < n; j++) {
        const int i = d->index[j];
        mat_mul(d->c, p, N_MEAS, N_STATE, N_STATE, cp); /* C P */
        mat_mul(cp, ct, N_MEAS, N_STATE, N_MEAS, s);    /* S = C P C^T + V */
        for (int q = 0; q < N_MEAS * N_MEAS; q++) s[q] += noise->v[q];
        for (int r = 0; r < N_MEAS; r++) /* S symmetric: its upper triangle onto the lower, as NumPy's solve sees it */
            for (int q = 0; q < r; q++) s[r * N_MEAS + q] = s[q * N_MEAS + r] = 0.5 * (s[r * N_MEAS + q] + s[q * N_MEAS + r]);
        for (int r = 0; r < N_MEAS; r++) { /* Cholesky S = L L^T, in place (lower) */
            for (int q = 0; q <= r; q++) {
                double sum = s[r * N_MEAS + q];
                for (int t = 0; t < q; t++) sum -= s[r * N_MEAS + t] * s[q * N_MEAS + t];
                if (q == r) {
                    if (!(sum > 0.0)) {
                        free(gains), free(p);
                        glue_log(inst, fmi2Error, "the predictor's filter: the innovation covariance at sample %ld "
                                 "is not positive definite", j);
                        return -1;
                    }
                    s[r * N_MEAS + r] = sqrt(sum);
                } else {
                    s[r * N_MEAS + q] = sum / s[q * N_MEAS + q];
                }
            }
        }
        double *gain = gains + (size_t)j * N_STATE * N_MEAS; /* M = P C^T S^-1: solve S M^T = C P, column by column */
        for (int col = 0; col < N_STATE; col++) {
            double y[N_MEAS];
            for (int r = 0; r < N_MEAS; r++) {
                double sum = cp[r * N_STATE + col];
                for (int t = 0; t < r; t++) sum -= s[r * N_MEAS + t] * y[t];
                y[r] = sum / s[r * N_MEAS + r];
            }
            for (int r = N_MEAS - 1; r >= 0; r--) {
                double sum = y[r];
                for (int t = r + 1; t < N_MEAS; t++) sum -= s[t * N_MEAS + r] * y[t];
                y[r] = sum / s[r * N_MEAS + r];
            }
            for (int r = 0; r < N_MEAS; r++) gain[col * N_MEAS + r] = y[r];
        }
        /* P <- Phi (I - M C) P Phi^T + W */
        mat_mul(gain, cp, N_STATE, N_MEAS, N_STATE, a); /* M C P */
        for (int q = 0; q < N_STATE * N_STATE; q++) a[q] = p[q] - a[q];
        const double *phi = g->phi + (size_t)i * N_STATE * N_STATE;
        mat_mul(phi, a, N_STATE, N_STATE, N_STATE, b);
        for (int r = 0; r < N_STATE; r++)
            for (int q = 0; q < N_STATE; q++) phi_t[r * N_STATE + q] = phi[q * N_STATE + r];
        mat_mul(b, phi_t, N_STATE, N_STATE, N_STATE, p);
        const double *w = noise->w + (size_t)i * N_STATE * N_STATE;
        for (int q = 0; q < N_STATE * N_STATE; q++) p[q] += w[q];
        for (int r = 0; r < N_STATE; r++)
            for (int q = 0; q < r; q++) p[r * N_STATE + q] = p[q * N_STATE + r] = 0.5 * (p[r * N_STATE + q] + p[q * N_STATE + r]);
    }
    free(p);
    free(d->gains);
    d->gains = gains, d->n_gains = n;
    return 0;
}
