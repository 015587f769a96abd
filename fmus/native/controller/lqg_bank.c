/*
 * The multiple-model LQG of controller_lqg's estimator = 2 (payload_bank): flexarm.lqg_bank.BankController.step
 * in C. Filters 0 .. n_models - 1 identify the payload (one per mass, the first 0 kg), the last one is the quiet
 * filter. Per 1 ms sample k, with d, j, c(i) and the schedule point as in controller_lqg.c:
 *   1. each filter: time update to j with its drift, x = Phi x_post + Gamma du_(j-1) + drift(c(j-1));
 *      innovation e = dm - C x; the identification filters add -(e' S_inv e + log det S) / 2 to their model's
 *      log posterior; x_post = x + M e; predictor to k with the torques sent at j .. k-1, drift included
 *   2. the log posterior: minus its log-sum-exp, floored at log_floor, minus its log-sum-exp again (a left fold of
 *      NumPy's logaddexp, as np.logaddexp.reduce); p = exp(log_p) (flexarm.filter_law.normalised_posterior)
 *   3. p_0 < reseed_below: the quiet filter takes the unloaded identification filter's estimates
 *   4. torque: tau = sat(tau_ff - sum_f w_f (K_f x_now_f + K_xi,f xi)), w = (0, p_1 .. p_(n-1), p_0): the quiet
 *      filter stands in for the unloaded model
 *   5. integral action: xi += dt C_q sum_f w_f x_now_f, only in a sample whose torque does not saturate
 * The arithmetic of every step is flexarm/filter_law.py's, generated (control_law_api.h; its exp and log1p are
 * portable_math's), and so is the drift d_j = psi(point of j) delta_acceleration_j formed at instantiation
 * (flexarm.lqg_bank.drift_along_path): this file says which filter, sample and design point, in which order. Resource: lqg_bank_<schedule>.txt
 * (fmu_build/native_resources.py).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "control_law_api.h"
#include "controller_lqg.h"

/* -- resources -------------------------------------------------------------------------------------------- */
void bank_free(Bank *b)
{
    free(b->times), free(b->c), free(b->phi), free(b->gamma), free(b->m), free(b->k), free(b->k_integral);
    free(b->s_inv), free(b->log_det_s), free(b->psi), free(b->delta_acceleration), free(b->drift), free(b->index);
    memset(b, 0, sizeof *b);
}

static int read_count(Instance *inst, const char *file, const char *text, const char *name, int lo, int hi, int *out)
{
    double v;
    if (glue_read_doubles(inst, file, text, name, &v, 1)) return -1;
    if (!(v >= lo && v <= hi) || v != floor(v)) {
        glue_log(inst, fmi2Error, "resources/%s: '%s' = %g, expected a whole number in %d..%d", file, name, v, lo, hi);
        return -1;
    }
    *out = (int)v;
    return 0;
}

int bank_load(Instance *inst, const char *file, const char *text, LqgData *d)
{
    Bank *b = &d->bank;
    if (read_count(inst, file, text, "n_models", 2, MAX_FILTERS - 1, &b->n_models) ||
        read_count(inst, file, text, "n_filters", b->n_models + 1, b->n_models + 1, &b->n_filters) ||
        read_count(inst, file, text, "count", 1, 1000000, &b->count) ||
        glue_read_doubles(inst, file, text, "schedule_period", &b->schedule_period, 1) ||
        glue_read_doubles(inst, file, text, "log_floor", &b->log_floor, 1) ||
        glue_read_doubles(inst, file, text, "reseed_below", &b->reseed_below, 1) ||
        glue_read_doubles(inst, file, text, "initial_log_p", b->initial_log_p, (size_t)b->n_models))
        return -1;
    const size_t nf = (size_t)b->n_filters, per = nf * (size_t)b->count, rows = (size_t)d->n_steps + 1;
    b->times = lqg_read_array(inst, file, text, "times", (size_t)b->count);
    b->c = lqg_read_array(inst, file, text, "C", nf * N_MEAS * N_STATE);
    b->phi = lqg_read_array(inst, file, text, "Phi", per * N_STATE * N_STATE);
    b->gamma = lqg_read_array(inst, file, text, "Gamma", per * N_STATE * 2);
    b->m = lqg_read_array(inst, file, text, "M", per * N_STATE * N_MEAS);
    b->k = lqg_read_array(inst, file, text, "K", per * N_WEIGHTS * 2 * N_STATE);
    b->k_integral = lqg_read_array(inst, file, text, "K_integral", per * N_WEIGHTS * 2 * N_AUG);
    b->s_inv = lqg_read_array(inst, file, text, "S_inv", per * N_MEAS * N_MEAS);
    b->log_det_s = lqg_read_array(inst, file, text, "log_det_S", per);
    b->psi = lqg_read_array(inst, file, text, "psi", per * N_STATE * N_ELEMENTS);
    b->delta_acceleration = lqg_read_array(inst, file, text, "delta_acceleration", nf * rows * N_ELEMENTS);
    b->drift = malloc(nf * rows * N_STATE * sizeof *b->drift);
    b->index = malloc(rows * sizeof *b->index);
    if (!b->times || !b->c || !b->phi || !b->gamma || !b->m || !b->k || !b->k_integral || !b->s_inv ||
        !b->log_det_s || !b->psi || !b->delta_acceleration || !b->drift || !b->index) {
        if (!b->drift || !b->index) glue_log(inst, fmi2Error, "resources/%s: out of memory for the drift", file);
        return -1;
    }
    if (lqg_split_integral_gain(b->k_integral, per * N_WEIGHTS * 2)) {
        glue_log(inst, fmi2Error, "resources/%s: out of memory for 'K_integral'", file);
        return -1;
    }
    lqg_schedule_index(b->times, b->count, d->n_steps, d->dt, b->index);
    for (size_t f = 0; f < nf; f++) {
        const size_t at = f * (size_t)b->count;
        b->filters[f] = (Design){b->count, b->times, b->phi + at * N_STATE * N_STATE, b->gamma + at * N_STATE * 2,
                                 b->m + at * N_STATE * N_MEAS, b->k + at * N_WEIGHTS * 2 * N_STATE,
                                 b->k_integral + at * N_WEIGHTS * 2 * N_STATE,
                                 b->k_integral + per * N_WEIGHTS * 2 * N_STATE + at * N_WEIGHTS * 2 * 2};
        for (size_t j = 0; j < rows; j++) /* drift_along_path: psi[index_at(j dt)] @ delta_acceleration[j] */
            law_state_drift(b->psi + (at + (size_t)b->index[j]) * N_STATE * N_ELEMENTS,
                            b->delta_acceleration + (f * rows + j) * N_ELEMENTS, b->drift + (f * rows + j) * N_STATE);
    }
    return 0;
}

void bank_initial_state(const Bank *b, LqgState *s)
{
    for (int i = 0; i < b->n_models; i++) s->log_p[i] = b->initial_log_p[i]; /* uniform */
}

/* -- the law -------------------------------------------------------------------------------------------------- */
static long long clamp(const LqgData *d, long long k) { return k < d->n_steps ? k : d->n_steps; }

/* x <- Phi x + Gamma du + drift_f(i_drift) at point i (flexarm.filter_law.time_update with the drift). */
static void propagate_drift(const Bank *b, int f, int i, long long i_drift, long long rows, double *x,
                            const double du[2])
{
    lqg_propagate(&b->filters[f], i, x, du, b->drift + ((size_t)f * (size_t)rows + (size_t)i_drift) * N_STATE);
}

void bank_step(const LqgData *d, const LqgState *s, long long k, const double m[N_MEAS], const double limit[2],
               double tau[2], LqgState *next)
{
    const Bank *b = &d->bank;
    const int dl = d->delay, nf = b->n_filters, nm = b->n_models;
    const long long rows = (long long)d->n_steps + 1, j = k - dl > 0 ? k - dl : 0;
    const int fresh = k - dl >= 0, i_j = b->index[clamp(d, j)];
    const int first = fresh ? 1 : (int)(dl + 1 - k); /* the torques of samples j .. k - 1 */
    const double *y_d = d->desired + clamp(d, j) * N_MEAS;
    double x_now[MAX_FILTERS][N_STATE] = {{0.0}}; /* the filters past nf weighted 0 (the generated sums' length) */
    memset(next, 0, sizeof *next);
    memcpy(next->log_p, s->log_p, sizeof next->log_p);
    for (int f = 0; f < nf; f++) { /* 1 */
        const Design *g = &b->filters[f];
        double x[N_STATE], e[N_MEAS];
        memcpy(x, s->x_post[f], sizeof x);
        if (s->started && j > 0 && fresh) propagate_drift(b, f, b->index[clamp(d, j - 1)], clamp(d, j - 1), rows, x,
                                                          s->du[0]);
        law_innovation(x, b->c + (size_t)f * N_MEAS * N_STATE, m, y_d, e);
        if (fresh && j > 0 && f < nm) {
            const size_t at = (size_t)f * (size_t)b->count + (size_t)i_j;
            const double log_p = next->log_p[f];
            law_log_likelihood_update(&log_p, e, b->s_inv + at * N_MEAS * N_MEAS, &b->log_det_s[at], &next->log_p[f]);
        }
        law_updated(x, g->m + (size_t)i_j * N_STATE * N_MEAS, e, next->x_post[f]);
        memcpy(x_now[f], next->x_post[f], sizeof x_now[f]);
        for (int row = first, q = 0; row <= dl; row++, q++)
            propagate_drift(b, f, b->index[clamp(d, j + q)], clamp(d, j + q), rows, x_now[f], s->du[row]);
    }
    double log_p[MAX_FILTERS], active[MAX_FILTERS], p[MAX_FILTERS], w[MAX_FILTERS]; /* 2 */
    for (int i = 0; i < MAX_FILTERS; i++) log_p[i] = i < nm ? next->log_p[i] : -HUGE_VAL, active[i] = i < nm;
    law_normalised_posterior(log_p, active, &b->log_floor, log_p, p);
    for (int i = 0; i < nm; i++) next->log_p[i] = log_p[i];
    double quiet[N_STATE]; /* 3: the quiet filter re-seeded once the unloaded arm is ruled out */
    law_reseeded(&p[0], &b->reseed_below, next->x_post[nf - 1], next->x_post[0], quiet);
    memcpy(next->x_post[nf - 1], quiet, sizeof quiet);
    law_reseeded(&p[0], &b->reseed_below, x_now[nf - 1], x_now[0], quiet);
    memcpy(x_now[nf - 1], quiet, sizeof quiet);
    for (int i = 0; i < MAX_FILTERS; i++) w[i] = 0.0; /* 4 */
    for (int i = 1; i < nm; i++) w[i] = p[i];
    w[nf - 1] = p[0];
    const int i_k = b->index[clamp(d, k)];
    double ff[2], ff_cmd[2], u[MAX_FILTERS][2] = {{0.0}}, free_tau[2];
    lqg_feedforward(d, k, ff, ff_cmd);
    for (int f = 0; f < nf; f++) { /* each model's feedback on its own estimate (flexarm.filter_law.feedback) */
        const Design *g = &b->filters[f];
        if (d->integral) { /* the augmented gain's two blocks, split at reading */
            const size_t at = (size_t)i_k * N_WEIGHTS + d->weight;
            law_feedback_integral(g->k_integral + at * 2 * N_STATE, x_now[f], g->k_xi + at * 2 * 2, s->xi, u[f]);
        } else {
            law_feedback(g->k + ((size_t)i_k * N_WEIGHTS + d->weight) * 2 * N_STATE, x_now[f], u[f]);
        }
    }
    law_bank_free_torque(ff_cmd, w, u[0], free_tau);
    law_saturate(free_tau, limit, tau);
    if (d->integral) { /* 5: C_q of the quiet filter (the law's sensor map) on the weighted estimate */
        double x_sel[N_STATE];
        law_weighted_estimate(w, x_now[0], x_sel);
        law_integrated(s->xi, &d->dt, b->c + (size_t)(nf - 1) * N_MEAS * N_STATE, x_sel, tau, free_tau, next->xi);
    } else {
        next->xi[0] = s->xi[0], next->xi[1] = s->xi[1];
    }
    for (int row = 0; row < dl; row++) next->du[row][0] = s->du[row + 1][0], next->du[row][1] = s->du[row + 1][1];
    next->du[dl][0] = tau[0] - ff[0], next->du[dl][1] = tau[1] - ff[1];
    next->k = k + 1;
    next->started = 1;
}
