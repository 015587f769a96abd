/*
 * Native sensors FMU: flexarm.sensors.SensorBank in C (paper section 6).
 *
 * Per sample: true signal -> Butterworth low-pass (gauges, accelerometers; optional, second-order sections
 * designed as scipy.signal.butter(..., output="sos", fs) designs them (flexarm/filter_design.py), primed to steady state on the first
 * sample) -> + uniform noise from the bank's own PCG64 stream (12 draws per sample, NumPy's numbers for the
 * same seed) -> quantisation (encoder counter, A/D with saturation). With filters, noise and quantisation
 * off the outputs equal the inputs exactly. Segment lengths of the gauges come from resources/.
 * The per-sample arithmetic (a filter section, the priming, the noise, the quantisation) is not written here:
 * sensor_law_api.h's law_* functions are generated from flexarm/sensor_law.py (fmu_build/law_codegen.py), the
 * functions the Python FMU runs, and so is the filters' design (flexarm/filter_design.py).
 *
 * Sampling (direct feedthrough): the outputs at t_k are a pure function of the committed bank and the inputs
 * present (computed into a pending copy; reads change nothing); fmi2DoStep commits the sample of the inputs
 * present then, and a step of n sample periods takes the n - 1 samples inside the step with the inputs held.
 * A step of 0 samples (within 1e-9 s) does nothing. The plant's sample_index is passed on as sample_index_m as
 * present at the sample (flexarm/loop_index.py); a master's placeholder (index 0, every input exactly 0) is not
 * measured (sample_or_skip).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_glue.h"
#include "loop_index.h"
#include "model_vars.h"
#include "pcg64.h"
#include "portable_math.h"
#include "sensor_law_api.h"

#define N_SIGNALS 12
#define MAX_SECTIONS 4

typedef struct {
    double sos[MAX_SECTIONS][6];
    double zi[MAX_SECTIONS][2];
    int n_sections;
} Filter;

typedef struct {
    Pcg64 rng;
    double strain_state[MAX_SECTIONS][6][2];
    double acc_state[MAX_SECTIONS][2][2];
    int primed;
    double n_samples;
    /* the plant sample measured at the last communication point (-1: none, or samples taken inside a step since),
     * with its inputs and its measurement: the same sample with the same values is the same measurement */
    double last_sample, last_input[N_SIGNALS], last_output[N_SIGNALS];
} Bank;

typedef struct {
    /* settings derived at initialisation */
    double amplitude[N_SIGNALS], adc_lsb[N_SIGNALS], encoder_lsb, code_lo, code_hi, period;
    int noise, encoder_quant, adc_quant, strain_filter, acc_filter;
    Filter strain, acc;
    Bank committed, pending;
} SensorsState;

typedef struct {
    double segment_lengths[6];
} SensorsData;

static const int TRUE_IDX[N_SIGNALS] = {IDX_q1, IDX_q2, IDX_qd1, IDX_qd2, IDX_eps1, IDX_eps2,
                                        IDX_eps3, IDX_eps4, IDX_eps5, IDX_eps6, IDX_acc1_n, IDX_acc2_n};
static const int MEASURED_IDX[N_SIGNALS] = {IDX_q1_m, IDX_q2_m, IDX_qd1_m, IDX_qd2_m, IDX_eps1_m, IDX_eps2_m,
                                            IDX_eps3_m, IDX_eps4_m, IDX_eps5_m, IDX_eps6_m, IDX_acc1_m, IDX_acc2_m};

/* -- Butterworth design at initialisation: generated from flexarm/filter_design.py, one function per order -- */
typedef void (*Design)(const double *tan_prewarp, double *out_sos, double *out_unit_state);
static const Design DESIGNS[LAW_BUTTERWORTH_ORDERS] = {
    law_butterworth_order_1, law_butterworth_order_2, law_butterworth_order_3, law_butterworth_order_4,
    law_butterworth_order_5, law_butterworth_order_6, law_butterworth_order_7, law_butterworth_order_8};

static void butter_sos(int order, double cutoff_hz, double fs, Filter *f) /* order in [1, 8]: the range check */
{
    double argument, tangent, sos[MAX_SECTIONS * 6], unit_state[MAX_SECTIONS * 2];
    law_prewarp_argument(&cutoff_hz, &fs, &argument);
    tangent = flexarm_tan(argument); /* the portable tangent: the same bits on every platform */
    DESIGNS[order - 1](&tangent, sos, unit_state);
    f->n_sections = (order + 1) / 2;
    memcpy(f->sos, sos, (size_t)f->n_sections * sizeof f->sos[0]);
    memcpy(f->zi, unit_state, (size_t)f->n_sections * sizeof f->zi[0]);
}

static void filter_prime(const Filter *f, double state[][2], int stride, const double *x, int n)
{
    for (int k = 0; k < f->n_sections; k++)
        for (int c = 0; c < n; c++) law_primed_state(f->zi[k], &x[c], state[k * stride + c]);
}

static void filter_step(const Filter *f, double state[][2], int stride, const double *x, double *y, int n)
{
    for (int c = 0; c < n; c++) {
        double v = x[c];
        for (int k = 0; k < f->n_sections; k++) {
            double *st = state[k * stride + c];
            const double xk = v, s0 = st[0], s1 = st[1];
            law_filter_section(f->sos[k], &s0, &s1, &xk, &v, &st[0], &st[1]);
        }
        y[c] = v;
    }
}

/* One sample of flexarm.sensors.SensorBank.measure. */
static void measure(const SensorsState *s, Bank *bank, const double *x, double *y)
{
    if (!bank->primed) {
        if (s->strain_filter) filter_prime(&s->strain, &bank->strain_state[0][0], 6, x + 4, 6);
        if (s->acc_filter) filter_prime(&s->acc, &bank->acc_state[0][0], 2, x + 10, 2);
        bank->primed = 1;
    }
    memcpy(y, x, N_SIGNALS * sizeof *y);
    if (s->strain_filter) filter_step(&s->strain, &bank->strain_state[0][0], 6, x + 4, y + 4, 6);
    if (s->acc_filter) filter_step(&s->acc, &bank->acc_state[0][0], 2, x + 10, y + 10, 2);
    double u[N_SIGNALS];
    for (int i = 0; i < N_SIGNALS; i++) u[i] = pcg64_random(&bank->rng); /* always 12 draws */
    if (s->noise)
        for (int i = 0; i < N_SIGNALS; i++) {
            const double clean = y[i];
            law_with_noise(&clean, &s->amplitude[i], &u[i], &y[i]);
        }
    static const double unbounded[2] = {-HUGE_VAL, HUGE_VAL}; /* the encoders' counter: no saturation */
    if (s->encoder_quant)
        for (int i = 0; i < 2; i++) {
            const double v = y[i];
            law_quantize(&v, &s->encoder_lsb, &unbounded[0], &unbounded[1], &y[i]);
        }
    if (s->adc_quant)
        for (int i = 2; i < N_SIGNALS; i++) {
            const double v = y[i];
            law_quantize(&v, &s->adc_lsb[i], &s->code_lo, &s->code_hi, &y[i]);
        }
    bank->n_samples += 1;
}

/* flexarm.sensors.SensorBank.skip: a master's placeholder (no index, every input exactly 0) is not measured: no
 * noise draw (the n-th real measurement gets the n-th draws), the filters keep their state, the outputs are 0. */
static void sample_or_skip(const SensorsState *s, Bank *bank, const double *x, double index, double *y)
{
    if (!loop_is_placeholder(index, x, N_SIGNALS)) {
        measure(s, bank, x, y);
        return;
    }
    memset(y, 0, N_SIGNALS * sizeof *y);
}

/* The sample at a communication point. A measurement belongs to the plant sample it measures: inputs that carry
 * the index of the sample measured at the last communication point, with the same values, are that sample again
 * (a Jacobi master sets the plant's outputs of t_(k-1) at t_k), and get its measurement, not a second sample of
 * it (no filter update, no noise draw). So the measurement of plant sample j is the same in every master, only
 * the time it reaches the controller differs (docs/sensors.md, "Which sample a measurement belongs to"). */
static void sample_at_point(const SensorsState *s, Bank *bank, const double *x, double index, double *y)
{
    double j;
    const int indexed = loop_received_index(index, &j);
    if (indexed && j == bank->last_sample && memcmp(x, bank->last_input, sizeof bank->last_input) == 0) {
        memcpy(y, bank->last_output, sizeof bank->last_output);
        return;
    }
    sample_or_skip(s, bank, x, index, y);
    bank->last_sample = indexed ? j : -1.0;
    memcpy(bank->last_input, x, sizeof bank->last_input);
    memcpy(bank->last_output, y, sizeof bank->last_output);
}

/* -- model callbacks ------------------------------------------------------------------------------ */
static int sensors_load(Instance *inst, char *const *contents, const size_t *sizes)
{
    (void)sizes;
    SensorsData *d = calloc(1, sizeof *d);
    if (d == NULL) return -1;
    if (glue_read_doubles(inst, MODEL_INFO.resources[0].file, contents[0], "strain_gauge_segment_lengths",
                          d->segment_lengths, 6)) {
        free(d);
        return -1;
    }
    inst->data = d;
    return 0;
}

static void sensors_unload(Instance *inst)
{
    free(inst->data);
    inst->data = NULL;
}

static fmi2Status sensors_initialize(Instance *inst)
{
    SensorsState *s = inst->state;
    const SensorsData *d = inst->data;
    double period = VALUE(inst, IDX_sample_period), nyquist = 0.5 / period;
    static const struct {
        int idx;
        const char *name;
    } cutoffs[2] = {{IDX_strain_gauge_cutoff_hz, "strain_gauge_cutoff_hz"},
                    {IDX_accelerometer_cutoff_hz, "accelerometer_cutoff_hz"}};
    for (int i = 0; i < 2; i++)
        if (!(VALUE(inst, cutoffs[i].idx) < nyquist)) {
            glue_log(inst, fmi2Error, "fmi2ExitInitializationMode: %s: %g Hz is outside the allowed range (0, %g) "
                     "Hz (the Nyquist frequency at sample_period = %g s)", cutoffs[i].name,
                     VALUE(inst, cutoffs[i].idx), nyquist, period);
            return fmi2Error;
        }
    memset(s, 0, sizeof *s);
    s->period = period;
    s->noise = VALUE(inst, IDX_noise_enabled) != 0;
    s->encoder_quant = VALUE(inst, IDX_encoder_quantization) != 0;
    s->adc_quant = VALUE(inst, IDX_adc_quantization) != 0;
    s->strain_filter = VALUE(inst, IDX_strain_gauge_filter) != 0;
    s->acc_filter = VALUE(inst, IDX_accelerometer_filter) != 0;
    const double settings[] = {VALUE(inst, IDX_encoder_noise_deg), VALUE(inst, IDX_tachometer_noise_deg_per_s),
                               VALUE(inst, IDX_strain_gauge_noise_deg), VALUE(inst, IDX_accelerometer_noise_m_per_s2),
                               VALUE(inst, IDX_encoder_counts_per_rev), VALUE(inst, IDX_tachometer_full_scale_deg_per_s)};
    const double gauge_fs[2] = {VALUE(inst, IDX_strain_gauge_full_scale_curvature_per_m_link1),
                                VALUE(inst, IDX_strain_gauge_full_scale_curvature_per_m_link2)};
    const double acc_fs = VALUE(inst, IDX_accelerometer_full_scale_m_per_s2);
    const double codes = ldexp(1.0, (int)VALUE(inst, IDX_adc_bits)); /* an n-bit converter's 2^n codes, exactly */
    double full_scale[N_SIGNALS - 2];
    law_channel_scales(&settings[0], &settings[1], &settings[2], &settings[3], &settings[4], &settings[5], gauge_fs,
                       d->segment_lengths, &acc_fs, &codes, s->amplitude, &s->encoder_lsb, full_scale, s->adc_lsb + 2,
                       &s->code_lo, &s->code_hi);
    if (s->strain_filter)
        butter_sos((int)VALUE(inst, IDX_strain_gauge_filter_order), VALUE(inst, IDX_strain_gauge_cutoff_hz),
                   1.0 / period, &s->strain);
    if (s->acc_filter)
        butter_sos((int)VALUE(inst, IDX_accelerometer_filter_order), VALUE(inst, IDX_accelerometer_cutoff_hz),
                   1.0 / period, &s->acc);
    pcg64_seed(&s->committed.rng, (uint64_t)VALUE(inst, IDX_noise_seed));
    s->committed.last_sample = -1.0;
    /* the sample at the start time, from the inputs present */
    double x[N_SIGNALS], y[N_SIGNALS];
    for (int i = 0; i < N_SIGNALS; i++) x[i] = VALUE(inst, TRUE_IDX[i]);
    s->pending = s->committed;
    sample_at_point(s, &s->pending, x, VALUE(inst, IDX_sample_index), y);
    for (int i = 0; i < N_SIGNALS; i++) VALUE(inst, MEASURED_IDX[i]) = y[i];
    VALUE(inst, IDX_sample_index_m) = VALUE(inst, IDX_sample_index); /* the plant sample measured */
    return fmi2OK;
}

static fmi2Status sensors_sample(Instance *inst)
{
    SensorsState *s = inst->state;
    double x[N_SIGNALS], y[N_SIGNALS];
    for (int i = 0; i < N_SIGNALS; i++) x[i] = VALUE(inst, TRUE_IDX[i]);
    s->pending = s->committed; /* re-set inputs re-measure from the same state */
    sample_at_point(s, &s->pending, x, VALUE(inst, IDX_sample_index), y);
    for (int i = 0; i < N_SIGNALS; i++) VALUE(inst, MEASURED_IDX[i]) = y[i];
    VALUE(inst, IDX_sample_index_m) = VALUE(inst, IDX_sample_index); /* the plant sample measured */
    return fmi2OK;
}

static fmi2Status sensors_do_step(Instance *inst, double t, double h)
{
    SensorsState *s = inst->state;
    double n;
    if (glue_whole_samples(h, s->period, &n)) {
        glue_log(inst, fmi2Error, "fmi2DoStep: step_size: %.17g s at t = %.17g s is not a whole multiple of the "
                 "parameter sample_period = %.17g s (within %g s; the filters are discretised for that period; the "
                 "FMU samples at its period inside a longer step, holding its inputs)", h, t, s->period,
                 GLUE_STEP_TOLERANCE);
        return fmi2Error;
    }
    if (n == 0) return fmi2OK; /* no sample instant in the step: nothing changes */
    double x[N_SIGNALS], y[N_SIGNALS];
    for (int i = 0; i < N_SIGNALS; i++) x[i] = VALUE(inst, TRUE_IDX[i]);
    for (double k = 1; k < n; k++) sample_or_skip(s, &s->pending, x, VALUE(inst, IDX_sample_index), y);
    if (n > 1) s->pending.last_sample = -1.0; /* samples of the held inputs since: the next one is new */
    s->committed = s->pending;
    return fmi2OK;
}

const ModelInfo MODEL_INFO = {
    MODEL_IDENTIFIER_STRING, MODEL_GUID_STRING, MODEL_VARS, MODEL_N_VARS, MODEL_RESOURCES, MODEL_N_RESOURCES,
    sizeof(SensorsState), sensors_load, sensors_unload, sensors_initialize, sensors_sample, sensors_do_step,
};
