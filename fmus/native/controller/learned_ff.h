/* The learned feedforward correction of the controller FMUs (learned_ff.c; flexarm.ilc design files). */
#ifndef FLEXARM_LEARNED_FF_H
#define FLEXARM_LEARNED_FF_H

#include "fmi2_glue.h"

/* Read the learned-feedforward file in the FMU's resources (LEARNED_FF_RESOURCE with its .json; neither: none)
 * into *correction (malloc'ed, *rows x 2 N.m; NULL and 0 for none), checking its .json: its seal, the npz's
 * SHA-256 and the trajectory and parameter files' (the FMU's, given). fmi2Error, logged naming the file and the
 * reason. */
fmi2Status learned_ff_load(Instance *inst, const char *trajectory_sha256, const char *parameter_sha256,
                           double **correction, long *rows);

#endif
