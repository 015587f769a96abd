/* Tables of live handles: see live_table.h. */
#include "live_table.h"

#include <stdlib.h>

#if defined(_MSC_VER)
#include <windows.h>
static volatile LONG registry_lock;
static void registry_acquire(void)
{
    while (InterlockedExchange(&registry_lock, 1)) Sleep(0);
}
static void registry_release(void) { InterlockedExchange(&registry_lock, 0); }
#else
static char registry_lock;
static void registry_acquire(void)
{
    while (__atomic_test_and_set(&registry_lock, __ATOMIC_ACQUIRE)) {
    }
}
static void registry_release(void) { __atomic_clear(&registry_lock, __ATOMIC_RELEASE); }
#endif

static long live_find(const LiveTable *t, const void *handle)
{
    for (size_t i = 0; i < t->n; i++)
        if (t->items[i].handle == handle) return (long)i;
    return -1;
}

int live_add(LiveTable *t, void *handle, const void *owner)
{
    registry_acquire();
    if (t->n == t->cap) {
        size_t cap = t->cap ? 2 * t->cap : 16;
        Live *items = realloc(t->items, cap * sizeof *items);
        if (items == NULL) {
            registry_release();
            return -1;
        }
        t->items = items, t->cap = cap;
    }
    t->items[t->n++] = (Live){handle, owner};
    registry_release();
    return 0;
}

int live_remove(LiveTable *t, const void *handle)
{
    registry_acquire();
    long i = live_find(t, handle);
    if (i >= 0) t->items[i] = t->items[--t->n];
    registry_release();
    return i >= 0;
}

int live_contains(LiveTable *t, const void *handle)
{
    registry_acquire();
    int found = live_find(t, handle) >= 0;
    registry_release();
    return found;
}

void *live_take_owned(LiveTable *t, const void *owner)
{
    void *handle = NULL;
    registry_acquire();
    for (size_t i = 0; i < t->n && handle == NULL; i++)
        if (t->items[i].owner == owner) {
            handle = t->items[i].handle;
            t->items[i] = t->items[--t->n];
        }
    registry_release();
    return handle;
}
