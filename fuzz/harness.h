/* The frame of every fuzz target: one(data, len) judges one input and abort()s when a rule
 * the C core promises is broken, so AFL++ records it as a crash.  Built by afl-clang-fast or
 * afl-gcc-fast, the target runs in AFL++'s persistent mode (the input in shared memory, many
 * inputs a process); built by any other compiler it reads one input from stdin, so a crash
 * replays with `fuzz/TARGET < the-crash-file` (scripts/fuzz.sh builds both). */
#ifndef MBGW_FUZZ_HARNESS_H
#define MBGW_FUZZ_HARNESS_H

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>

static void one(const uint8_t *data, size_t len);

/* A rule broken: say which, and crash. */
#define MUST(cond)                                                                      \
    do {                                                                                \
        if (!(cond)) {                                                                  \
            fprintf(stderr, "%s:%d: broken: %s\n", __FILE__, __LINE__, #cond);          \
            abort();                                                                    \
        }                                                                               \
    } while (0)

/* A copy of data[0..len) in a block of exactly len bytes, so that AddressSanitizer sees a
 * read past it. */
static uint8_t *exact_copy(const uint8_t *data, size_t len)
{
    uint8_t *copy = malloc(len ? len : 1);
    MUST(copy != NULL);
    for (size_t i = 0; i < len; i++)
        copy[i] = data[i];
    return copy;
}

#define MAX_INPUT 4096

#ifdef __AFL_FUZZ_TESTCASE_LEN
__AFL_FUZZ_INIT();

int main(void)
{
    __AFL_INIT();
    const uint8_t *buf = __AFL_FUZZ_TESTCASE_BUF;
    while (__AFL_LOOP(100000)) {
        size_t len = (size_t)__AFL_FUZZ_TESTCASE_LEN;
        one(buf, len > MAX_INPUT ? MAX_INPUT : len);
    }
    return 0;
}
#else
int main(void)
{
    static uint8_t buf[MAX_INPUT];
    size_t len = 0;
    ssize_t n;
    while (len < sizeof buf && (n = read(0, buf + len, sizeof buf - len)) > 0)
        len += (size_t)n;
    one(buf, len);
    return 0;
}
#endif

#endif
