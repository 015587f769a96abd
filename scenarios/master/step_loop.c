/*
 * The master's stepping loop in C, for FMUs loaded in the master's process (scenarios/master/step_loop.py).
 *
 * It makes the same FMI calls in the same order as the Python loop of scenarios.master.cosim.Master.run: per
 * communication point k the plan's operations (one fmi2GetReal per port into its buffer, one fmi2SetReal per link
 * from values gathered out of a port's buffer), the recorded values gathered into row k, the divergence check,
 * then fmi2DoStep of every FMU in order. Only the loop's own cost goes (about 13 us a step in Python, ten ctypes
 * calls and a few NumPy operations); the FMUs see nothing different.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>

typedef int (*get_real_fn)(void *, const unsigned int *, size_t, double *);
typedef int (*set_real_fn)(void *, const unsigned int *, size_t, const double *);
typedef int (*do_step_fn)(void *, double, double, int);

/* One operation of the plan: kind 0 reads a port, kind 1 writes a link. */
typedef struct {
    int64_t kind;
    int64_t unit;             /* the FMU read (port) or written (link) */
    void *function;           /* its fmi2GetReal or fmi2SetReal */
    void *component;
    const unsigned int *vrs;
    int64_t n;
    double *buffer;           /* port: its values; link: the values it sets */
    const double *source;     /* link: the port buffer it gathers from */
    const int64_t *index;     /* link: positions in that buffer, n of them */
} step_op;

typedef struct {
    void *do_step;
    void *component;
} step_unit;

/* One port's recorded values: data[k, cols[i]] = source[pos[i]]. */
typedef struct {
    const double *source;
    const int64_t *cols;
    const int64_t *pos;
    int64_t n;
} step_gather;

enum { STEP_DONE = 0, STEP_UNBOUNDED = 1, STEP_FAILED = 2 };
enum { FN_GET_REAL = 0, FN_SET_REAL = 1, FN_DO_STEP = 2 };

/*
 * Communication points k0 .. k1 - 1 (k1 <= n_last + 1): at each the operations, the row, the check, and
 * (unless k == n_last) the steps. Returns STEP_DONE, STEP_UNBOUNDED (out[0] = k, out[1] = the first column out
 * of bounds) or STEP_FAILED (out[0] = k, out[2] = FN_*, out[3] = unit, out[4] = status). out[5] is the last
 * row gathered (-1 before any).
 */
int64_t flexarm_step_loop(int64_t k0, int64_t k1, int64_t n_last, const double *time, const double *steps,
                          int64_t n_ops, const step_op *ops, int64_t n_units, const step_unit *units,
                          int64_t n_gathers, const step_gather *gathers, double *data, int64_t n_cols,
                          double limit, int64_t *out)
{
    out[5] = k0 - 1;
    for (int64_t k = k0; k < k1; k++) {
        out[0] = k;
        for (int64_t i = 0; i < n_ops; i++) {
            const step_op *op = &ops[i];
            int status;
            if (op->kind == 0) {
                status = ((get_real_fn)op->function)(op->component, op->vrs, (size_t)op->n, op->buffer);
            } else {
                for (int64_t j = 0; j < op->n; j++)
                    op->buffer[j] = op->source[op->index[j]];
                status = ((set_real_fn)op->function)(op->component, op->vrs, (size_t)op->n, op->buffer);
            }
            if (status > 1) {
                out[2] = op->kind == 0 ? FN_GET_REAL : FN_SET_REAL;
                out[3] = op->unit;
                out[4] = status;
                return STEP_FAILED;
            }
        }
        double *row = data + k * n_cols;
        for (int64_t g = 0; g < n_gathers; g++)
            for (int64_t i = 0; i < gathers[g].n; i++)
                row[gathers[g].cols[i]] = gathers[g].source[gathers[g].pos[i]];
        out[5] = k;
        for (int64_t c = 0; c < n_cols; c++) {
            if (!(fabs(row[c]) < limit)) { /* NaN and inf too */
                out[1] = c;
                return STEP_UNBOUNDED;
            }
        }
        if (k == n_last)
            return STEP_DONE;
        for (int64_t u = 0; u < n_units; u++) {
            int status = ((do_step_fn)units[u].do_step)(units[u].component, time[k], steps[k], 1);
            if (status > 1) {
                out[2] = FN_DO_STEP;
                out[3] = u;
                out[4] = status;
                return STEP_FAILED;
            }
        }
    }
    return STEP_DONE;
}
