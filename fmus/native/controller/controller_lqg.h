/*
 * What controller_lqg.c (the FMU, the single Kalman filter) and lqg_bank.c (the payload bank) share: the
 * sizes, a design's arrays, the controller's state and the steps both take.
 */
#ifndef FLEXARM_CONTROLLER_LQG_H
#define FLEXARM_CONTROLLER_LQG_H

#include "control_law_api.h"
#include "fmi2_glue.h"

#define N_MEAS 10
#define N_STATE 22
#define N_ELEMENTS 11 /* element accelerations of the bank's drift */
#define N_AUG (N_STATE + 2)
#define N_WEIGHTS 4
#define MAX_DELAY 10
#define MAX_FILTERS LAW_BANK_FILTERS /* room for the bank's filters (the resource says how many: 9) */

typedef struct {
    int count;
    double *times, *phi, *gamma, *m; /* count; count x 22 x 22; count x 22 x 2; count x 22 x 10 */
    double *k;                       /* count x 4 x 2 x 22 */
    double *k_integral, *k_xi;       /* [K K_xi] split at reading: count x 4 x 2 x 22, count x 4 x 2 x 2 */
} Design;

/* The payload bank (flexarm.lqg_bank.PayloadBank): the identification filters by mass, then the quiet filter. */
typedef struct {
    int n_models, n_filters, count;
    double schedule_period; /* s: the schedule the bank was designed on */
    double log_floor, reseed_below, initial_log_p[MAX_FILTERS];
    double *times;                            /* count, s (the quiet filter's, = every filter's) */
    double *c;                                /* n_filters x 10 x 22 */
    double *phi, *gamma, *m, *k, *k_integral; /* stacked over the filters as Design's (k_integral: all the K
                                                 blocks, then all the K_xi blocks, lqg_split_integral_gain) */
    double *s_inv, *log_det_s;                /* n_filters x count x 10 x 10; n_filters x count */
    double *psi, *delta_acceleration;         /* n_filters x count x 22 x 11; n_filters x (n_steps + 1) x 11 */
    double *drift;                            /* n_filters x (n_steps + 1) x 22, psi delta_acceleration */
    Design filters[MAX_FILTERS];              /* views into the stacked arrays */
    int *index;                               /* n_steps + 1: the point in force at each sample */
} Bank;

typedef struct {
    int n_steps;
    double dt;
    double *feedforward, *desired; /* (n_steps + 1) x 2 N.m; (n_steps + 1) x 10 desired measurements */
    double c[N_MEAS * N_STATE];    /* the sensor map */
    Design *designs;               /* one per schedule */
    Bank bank;
    /* the configuration in force (from the parameters) */
    double key[5];
    const Design *design;
    int weight, delay, integral, use_bank;
    int *index; /* n_steps + 1: the design point in force at each sample */
    double *correction; /* n_correction x 2: the learned feedforward correction (NULL: none), N.m */
    long n_correction;
    /* the time-varying filter's gains of samples 0 .. n_gains - 1 (lqg_transient_gains; NULL: the design's
       steady gain of each point throughout), made as the run needs them: samples 0 .. gains_made - 1 so far, from
       the covariance gains_p of sample gains_made and the noise model gains_noise (lqg_gains_through) */
    double *gains, *gains_p;
    long n_gains, gains_made;
    const struct Noise *gains_noise;
} LqgData;

/* A design's noise model (resources lqg_<schedule>.txt: W, V and the steady prior covariance at its first point):
   what the time-varying filter's covariance recursion needs (flexarm.lqg_design.transient_gains). */
typedef struct Noise {
    double *w;                      /* count x 22 x 22 */
    double v[N_MEAS * N_MEAS];      /* 10 x 10 */
    double p_prior0[N_STATE * N_STATE];
} Noise;

/* The feedforward sent at sample k: the trajectory's (zero after the slew) plus the learned correction (into
 * command); the nominal one (into nominal), about which the filter's model is linearised. */
void lqg_feedforward(const LqgData *d, long long k, double nominal[2], double command[2]);

typedef struct {  /* flexarm.lqg.LqgState and flexarm.lqg_bank.BankState */
    long long k;  /* next sample */
    int started;  /* the filter has taken a measurement */
    double x_post[MAX_FILTERS][N_STATE]; /* each filter's posterior (the single Kalman filter: row 0) */
    double log_p[MAX_FILTERS];           /* the bank's log posterior of the models */
    double du[MAX_DELAY + 1][2];         /* torque deviations sent at k - 1 - d .. k - 1, oldest first */
    double xi[2];                        /* integrated joint-angle errors, rad s */
} LqgState;

/* lqg_core.c (shared with controller.c) */
static inline long long lqg_clamp(const LqgData *d, long long k) { return k < d->n_steps ? k : d->n_steps; }
/* A design resource's arrays into g (count, times, Phi, Gamma, M, K, K_integral) and the sensor map into c. */
int lqg_read_design(Instance *inst, const char *file, const char *text, Design *g, double *c);
/* Free a design's arrays and zero it (an unread design: times == NULL). */
void lqg_free_design(Design *g);
/* Steps 1-3: the posterior at j = max(k - d, 0) and the error predicted to sample k (d->design, d->delay). */
void lqg_estimate(const LqgData *d, const LqgState *s, long long k, const double m[N_MEAS], double x_post[N_STATE],
                  double x_now[N_STATE]);
/* A design resource's noise model (W, V, P_prior0) into `noise`. */
int lqg_read_noise(Instance *inst, const char *file, const char *text, int count, Noise *noise);
/* Start d->gains for samples 0 .. d->n_steps - 1 of d->design (its points d->index) from the prior covariance
   `factor` times the steady prior at sample 0 (flexarm.lqg_design.transient_gains); none is made yet
   (lqg_gains_through). -1 (logged) when out of memory. */
int lqg_transient_gains(Instance *inst, LqgData *d, const Noise *noise, double factor);
/* Make d->gains through sample k (or the last one), the covariance recursion's samples in order, so that a run
   spreads them over its steps instead of stalling one step for the whole slew (about 20 us each; a 2 s slew at
   1 ms: 40 ms). -1 (logged) when a gain is not finite (the LDL^T solve of the innovation covariance broke down:
   singular, or the recursion diverged). */
int lqg_gains_through(Instance *inst, LqgData *d, long long k);
/* Free d->gains and what makes them. */
void lqg_free_gains(LqgData *d);
/* The plant's reports of the torque it held (see lqg_core.c): a few are enough, a switch comes early. */
#define LQG_N_FOREIGN 16
int lqg_plant_applied(Instance *inst, long long k, int any_lag, double torque[2]);
void lqg_with_applied(const LqgData *d, LqgState *s, long long sample, const double torque[2]);
void lqg_remember(double foreign[][3], int *n, long long sample, const double torque[2]);
/* The controller's outputs: the torques and the index outputs (tau_index, loop_delay, loop_delay_assumed,
   slew_start_index). */
void lqg_set_outputs(Instance *inst, const double tau[2], const double index[4]);
/* The measurements at the inputs (q1_m .. eps6_m), in the order of the law's sensor map. */
void lqg_measurements(Instance *inst, double m[N_MEAS]);
/* At the first fmi2DoStep (at t = 0): 1, logged, with *start = 1, when the master read no output of this FMU since
   initialisation began and the inputs are its placeholder (it exchanged nothing before the step, so no torque of
   this FMU reached the plant over it): the slew then starts one sample later
   (flexarm_controller_base.ControllerSlave.starts_late, docs/control.md "The slew starts when the loop is live").
   Otherwise 0, *start unchanged. */
int lqg_starts_late(Instance *inst, double t, double dt, double *start);
/* The augmented gains [K K_xi] (rows x 24, as the resources hold them) rearranged in place into their K blocks
   (rows x 22) followed by their K_xi blocks (rows x 2), once at reading: the law takes them apart. -1: out of
   memory. */
int lqg_split_integral_gain(double *k_integral, size_t rows);
/* An array of n doubles labelled `name` in a resource text, malloc'ed (NULL after logging why not). */
double *lqg_read_array(Instance *inst, const char *file, const char *text, const char *name, size_t n);
/* x <- Phi x + Gamma du at design point i. */
void lqg_propagate(const Design *g, int i, double *x, const double du[2], const double *drift);
/* The point of `times` (count) in force at each sample k = 0 .. n_steps: the last time <= k dt + 1e-9. */
void lqg_schedule_index(const double *times, int count, int n_steps, double dt, int *index);

/* lqg_bank.c */
int bank_load(Instance *inst, const char *file, const char *text, LqgData *d);
void bank_free(Bank *b);
void bank_initial_state(const Bank *b, LqgState *s);
void bank_step(const LqgData *d, const LqgState *s, long long k, const double m[N_MEAS], const double limit[2],
               double tau[2], LqgState *next);

#endif
