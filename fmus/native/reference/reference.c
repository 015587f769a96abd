/*
 * Native reference FMU: flexarm.reference.ReferenceSignals in C.
 *
 * No inputs; one parameter, lead_samples = L (Integer 0..1000, range checked by the glue). The outputs at
 * communication point t are row min(k, n) of the table computed by flexarm.reference (resource reference.txt,
 * SHA-256 checked by the glue), k = lround(t / dt) + L:
 * the desired states, joint references, feedforward torques (0 after the slew), desired tip and progress,
 * in the order of the variable table (the signal catalogue's "reference" outputs). Row n (t = t_f) is held
 * after the slew. A step must be a whole number of samples (glue_whole_samples).
 */
#include <math.h>
#include <stdlib.h>

#include "fmi2_glue.h"
#include "model_vars.h"

typedef struct {
    int n_steps, n_outputs;
    double dt;
    double *table; /* (n_steps + 1) x n_outputs, columns in the order of the FMU's outputs */
    int output_index[MODEL_N_VARS];
} ReferenceData;

static void reference_unload(Instance *inst)
{
    ReferenceData *d = inst->data;
    if (d == NULL) return;
    free(d->table);
    free(d);
    inst->data = NULL;
}

static int reference_load(Instance *inst, char *const *contents, const size_t *sizes)
{
    (void)sizes;
    ReferenceData *d = calloc(1, sizeof *d);
    if (d == NULL) return -1;
    inst->data = d;
    const char *file = MODEL_INFO.resources[0].file, *text = contents[0];
    for (size_t i = 0; i < MODEL_N_VARS; i++)
        if (MODEL_VARS[i].causality == CA_OUTPUT) d->output_index[d->n_outputs++] = (int)i;
    double n, cols;
    if (glue_read_doubles(inst, file, text, "n_steps", &n, 1) || glue_read_doubles(inst, file, text, "dt", &d->dt, 1) ||
        glue_read_doubles(inst, file, text, "n_outputs", &cols, 1))
        goto fail;
    if ((int)cols != d->n_outputs) {
        glue_log(inst, fmi2Error, "%s: %d columns, but the FMU has %d outputs", file, (int)cols, d->n_outputs);
        goto fail;
    }
    d->n_steps = (int)n;
    d->table = malloc((size_t)(d->n_steps + 1) * (size_t)d->n_outputs * sizeof(double));
    if (d->table == NULL ||
        glue_read_doubles(inst, file, text, "table", d->table, (size_t)(d->n_steps + 1) * (size_t)d->n_outputs))
        goto fail;
    return 0;
fail:
    reference_unload(inst);
    return -1;
}

static fmi2Status reference_sample(Instance *inst)
{
    const ReferenceData *d = inst->data;
    long k = lround(inst->time / d->dt) + (long)VALUE(inst, IDX_lead_samples);
    if (k < 0) k = 0;
    if (k > d->n_steps) k = d->n_steps;
    const double *row = d->table + (size_t)k * (size_t)d->n_outputs;
    for (int j = 0; j < d->n_outputs; j++) VALUE(inst, d->output_index[j]) = row[j];
    return fmi2OK;
}

static fmi2Status reference_do_step(Instance *inst, double t, double h)
{
    const ReferenceData *d = inst->data;
    double n;
    if (glue_whole_samples(h, d->dt, &n)) {
        glue_log(inst, fmi2Error, "fmi2DoStep: step_size: %.17g s at t = %.17g s is not a whole multiple of the "
                 "reference's sample (%g s, the trajectory's sample time, within %g s)", h, t, d->dt,
                 GLUE_STEP_TOLERANCE);
        return fmi2Error;
    }
    return fmi2OK; /* stateless: the outputs are a function of the time */
}

const ModelInfo MODEL_INFO = {
    MODEL_IDENTIFIER_STRING, MODEL_GUID_STRING, MODEL_VARS, MODEL_N_VARS, MODEL_RESOURCES, MODEL_N_RESOURCES,
    0, reference_load, reference_unload, reference_sample, reference_sample, reference_do_step,
};
