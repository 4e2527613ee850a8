/* One context used from two threads at once, against the one-call-at-a-time contract: every
 * call must either run or be refused with SIE_STATUS_BUSY, and under helgrind there must be no
 * data race (the context's busy flag is a try-lock thread checkers understand; the message a
 * thread reads is its own copy). Which calls are refused depends on scheduling; the checks
 * below hold for every interleaving. */
#include <pthread.h>
#include <stdio.h>
#include <string.h>

#include "sie.h"

enum { POINTS = 300, REGISTRATIONS = 20, SETTER_CALLS = 20000 };

static sie_context *ctx;
static float source[3 * POINTS], target[3 * POINTS];

struct counts {
    int ran, busy, other;
};

static void *hammer(void *arg) {
    struct counts *counts = arg;
    for (int i = 0; i < SETTER_CALLS; ++i) {
        sie_status status = sie_context_set_seed(ctx, (uint64_t)i);
        /* This thread's copy: another thread's call cannot replace it while it is read. */
        const char *message = sie_context_last_error(ctx);
        if (status == SIE_STATUS_OK) {
            counts->ran++;
        } else if (status == SIE_STATUS_BUSY) {
            counts->busy++;
        } else {
            counts->other++;
        }
        if (message == NULL || strlen(message) > 1000) {
            counts->other++;
        }
    }
    return NULL;
}

int main(void) {
    for (int i = 0; i < POINTS; ++i) {
        source[3 * i] = (float)(i % 10);
        source[3 * i + 1] = (float)(i / 10 % 10);
        source[3 * i + 2] = (float)(i / 100) + 0.01f * (float)(i % 7);
        target[3 * i] = source[3 * i] + 0.01f;
        target[3 * i + 1] = source[3 * i + 1];
        target[3 * i + 2] = source[3 * i + 2];
    }
    ctx = sie_context_new();
    if (ctx == NULL || sie_context_set_threads(ctx, 1) != SIE_STATUS_OK) {
        puts("two_threads_test: setup failed");
        return 1;
    }
    struct counts other = {0, 0, 0}, mine = {0, 0, 0};
    pthread_t thread;
    if (pthread_create(&thread, NULL, hammer, &other) != 0) {
        puts("two_threads_test: pthread_create failed");
        return 1;
    }
    double transform[16];
    for (int i = 0; i < REGISTRATIONS; ++i) {
        sie_status status = sie_context_register(ctx, source, POINTS, 0, target, POINTS, 0, NULL, transform);
        if (status == SIE_STATUS_OK) {
            mine.ran++;
        } else if (status == SIE_STATUS_BUSY) {
            mine.busy++;
        } else {
            mine.other++;
        }
    }
    pthread_join(thread, NULL);
    /* Alone again: the context works normally. */
    int failed = mine.other + other.other;
    if (sie_context_register(ctx, source, POINTS, 0, target, POINTS, 0, NULL, transform) != SIE_STATUS_OK ||
        strcmp(sie_context_last_error(ctx), "") != 0) {
        failed++;
    }
    printf("two_threads_test: registrations %d ran, %d busy; setter calls %d ran, %d busy; %d failed\n",
           mine.ran, mine.busy, other.ran, other.busy, failed);
    sie_context_free(ctx);
    return failed == 0 ? 0 : 1;
}
