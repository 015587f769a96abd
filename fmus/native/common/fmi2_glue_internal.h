/* Shared by the glue's own files (fmi2_glue.c: state machine, logging, variables, lifecycle, stepping;
 * fmi2_glue_state.c: sealed FMU states), not by the models (they see fmi2_glue.h only). */
#ifndef FLEXARM_FMI2_GLUE_INTERNAL_H
#define FLEXARM_FMI2_GLUE_INTERNAL_H

#include "fmi2_glue.h"
#include "live_table.h"

/* The FMI state machine: the instance's states, and the calls whose allowed states fmi2_glue.c tabulates. */
enum { S_INSTANTIATED, S_INIT, S_STEP_COMPLETE, S_STEP_FAILED, S_TERMINATED, S_COUNT };

typedef enum {
    F_SET_DEBUG_LOGGING, F_SETUP_EXPERIMENT, F_ENTER_INIT, F_EXIT_INIT, F_TERMINATE, F_RESET, F_GET, F_SET,
    F_GET_STATE, F_SET_STATE, F_SERIALIZE, F_DO_STEP, F_STATUS, F_COUNT
} Call;

/* The instance if `call` is allowed in its state (it is a live instance of this FMU); otherwise NULL, logged. */
Instance *glue_admit(fmi2Component c, Call call);
/* The live FMU states of this binary (live_table.h), owned by the instance that made them. */
extern LiveTable glue_live_states;
/* Free an FMU state's memory (not its table entry). */
void glue_free_snapshot(void *snap);

#endif /* FLEXARM_FMI2_GLUE_INTERNAL_H */
