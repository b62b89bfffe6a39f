/* What the .c files of csrc/ share and Python does not see: build_ffi.py hands cffi
 * mbgw.h only, so this header may hold static inline code and #includes.  Its helpers
 * carry no mbgw_ prefix: they are not part of the interface. */
#ifndef MBGW_INTERNAL_H
#define MBGW_INTERNAL_H

#include <stddef.h>
#include <stdint.h>
#include <time.h>

/* RTU frames (Modbus over Serial Line V1.02, 2.5.1) */
#define CRC_LEN 2
#define MIN_FRAME 4 /* address, function code, CRC */
#define MIN_REPLY 5 /* the shortest reply: an exception (address, fc, code, CRC) */

/* MBAP header (Modbus Messaging on TCP/IP Implementation Guide V1.0b, 3.1.3): transaction
 * id, protocol id, length (of what follows: unit id + PDU), unit id. */
#define MBAP_HEAD_LEN 6     /* the bytes before those the length counts */
#define MBAP_LEN 7          /* with the unit id */
#define MBAP_MAX_LENGTH 254 /* the length: unit id + the largest PDU */

static inline int64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

#endif
