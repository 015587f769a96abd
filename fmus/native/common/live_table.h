/* Tables of live handles (instances, FMU states) of one FMU binary.
 *
 * A handle given by the host is dereferenced only once it is found in its table: a second fmi2FreeInstance, a
 * freed FMUstate, or another FMU's instance or state (another binary, hence other tables) is refused without its
 * memory being read. Shared by the native FMUs' glue (fmi2_glue.c) and the Python FMUs' C front end
 * (fmus/common/fmi2_shim*.c). One spin lock per binary guards every table (instances may live in different
 * threads); it is held only for a scan of a few pointers. */
#ifndef FLEXARM_LIVE_TABLE_H
#define FLEXARM_LIVE_TABLE_H

#include <stddef.h>

typedef struct {
    void *handle;
    const void *owner; /* states: the instance that made it (freed with it); instances: NULL */
} Live;

typedef struct {
    Live *items;
    size_t n, cap;
} LiveTable;

/* Add a handle; 0 on success, -1 out of memory. */
int live_add(LiveTable *t, void *handle, const void *owner);
/* 1 if the handle was live (and is now removed), 0 if it was not. */
int live_remove(LiveTable *t, const void *handle);
int live_contains(LiveTable *t, const void *handle);
/* Remove one handle made by `owner` and return it (to be freed by the caller); NULL when none is left. */
void *live_take_owned(LiveTable *t, const void *owner);

#endif /* FLEXARM_LIVE_TABLE_H */
