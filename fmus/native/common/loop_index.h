/*
 * The loop's sample indices, the C twin of flexarm/loop_index.py (docs/control.md, "The loop measures its own
 * delay"): sample k = round(t / 1 ms), counted from t = 0, travels as the index k + 1, so that 0 (a master's
 * zero fill, an unwired input) means "no sample yet". Whole numbers carried as Reals (exact up to 2^53).
 * Same rounding as Python's round (nearbyint: halves to even); tests/test_loop_index.py holds the two together.
 */
#ifndef FLEXARM_LOOP_INDEX_H
#define FLEXARM_LOOP_INDEX_H

#include <math.h>

#define LOOP_SAMPLE_PERIOD 1e-3 /* s: flexarm.loop_index.SAMPLE_PERIOD */
#define LOOP_NO_SAMPLE 0.0      /* flexarm.loop_index.NO_SAMPLE */
#define LOOP_NO_INDEX_LAG -1.0  /* flexarm.loop_index.NO_INDEX_LAG */
#define LOOP_NO_DELAY -1.0      /* flexarm.loop_index.NO_DELAY */
#define LOOP_AUTOMATIC -1       /* flexarm.loop_index.AUTOMATIC: loop_delay_samples measured */
#define LOOP_WHOLE 1e-6         /* an index within this of a whole number is that number */

/* flexarm.loop_index.index_of_time: k + 1 for t = k * 1 ms (nearest), LOOP_NO_SAMPLE before t = 0. */
static inline double loop_index_of_time(double t)
{
    const double k = nearbyint(t / LOOP_SAMPLE_PERIOD);
    return k >= 0.0 ? k + 1.0 : LOOP_NO_SAMPLE;
}

/* flexarm.loop_index.received_index: 1 and *k = the sample an index names, 0 for "no sample yet". */
static inline int loop_received_index(double value, double *k)
{
    if (!isfinite(value) || value < 1.0 - LOOP_WHOLE) return 0;
    const double whole = nearbyint(value);
    if (fabs(value - whole) > LOOP_WHOLE) return 0;
    *k = whole - 1.0;
    return 1;
}

/* flexarm.loop_index.torque_lag: how many samples late a torque held from step_start (s) is. */
static inline double loop_torque_lag(double step_start, double tau_index)
{
    double computed_for;
    if (!loop_received_index(tau_index, &computed_for)) return LOOP_NO_INDEX_LAG;
    return nearbyint(step_start / LOOP_SAMPLE_PERIOD) - computed_for;
}

/* flexarm.loop_index.measured_delay: k - j for the plant sample j the index names, LOOP_NO_DELAY for none. */
static inline double loop_measured_delay(double k, double index)
{
    double j;
    return loop_received_index(index, &j) ? k - j : LOOP_NO_DELAY;
}

/* flexarm.loop_index.is_placeholder: no index and every one of the n measurements exactly 0 (a master's fill). */
static inline int loop_is_placeholder(double index, const double *m, int n)
{
    double j;
    if (loop_received_index(index, &j)) return 0;
    for (int i = 0; i < n; i++)
        if (m[i] != 0.0) return 0;
    return 1;
}

/* flexarm.loop_index.trajectory_index: the master's index as the trajectory's for a slew started `start` samples
   late; a sample before the start names none. start 0: index itself. */
static inline double loop_trajectory_index(double index, double start)
{
    double j;
    if (start == 0.0 || !loop_received_index(index, &j)) return index;
    return j >= start ? j - start + 1.0 : LOOP_NO_SAMPLE;
}

#endif
