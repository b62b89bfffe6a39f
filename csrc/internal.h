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
#define MBAP_MIN_LENGTH 2   /* the length: unit id + function code */
#define MBAP_MAX_LENGTH 254 /* the length: unit id + the largest PDU */

/* A big-endian 16-bit field (Modbus's byte order). */
static inline unsigned be16(const uint8_t *p)
{
    return (unsigned)p[0] << 8 | p[1];
}

static inline int64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

/* --- capture.c --- */

/* Append what went on the line (MBGW_CAPTURE_RX or _TX) to the capture, if one is set. */
void capture_note(int direction, const uint8_t *bytes, size_t len);

/* --- line.c --- */

/* Wait for input until until_ns (CLOCK_MONOTONIC).  1 readable, 0 timed out, -errno on
 * error or hang-up. */
int wait_input(int fd, int64_t until_ns);

/* read() of at most cap bytes, EINTR retried.  Returns how many came, 0 none was
 * waiting, -EIO the tty hung up, else -errno. */
long read_some(int fd, uint8_t *buf, size_t cap);

/* --- mbap.c --- */

/* A lent client's input in[0..n): when it is exactly one Modbus TCP request with a valid
 * header whose unit id units maps to an address (0: not this line's) that down does not
 * mark, the request as it goes on the line (that address + the PDU) in adu, and its
 * length; else 0. */
size_t loan_request(const uint8_t *in, size_t n, const uint8_t *units,
                    const uint8_t *down, uint8_t *adu);

/* --- match.c: slave mode's reply among the bytes a burst on the line brought, req being
 * the request (address + PDU, no CRC) and buf[0..have) the burst so far --- */

/* The length of the frame the burst begins with, by its function code: > 0, 0 more bytes
 * are needed to tell, MBGW_LEN_UNKNOWN silence ends it, < 0 otherwise: no frame is that
 * long. */
int burst_head(size_t req_len, const uint8_t *buf, size_t have);

/* The frame to take from the burst: the whole frame with a valid CRC that it begins with
 * (head: burst_head's; ended: the burst is over, so a frame that silence ends ends here),
 * else the reply to req behind what cannot start it: req's address, its function or that
 * exception, its length, a valid CRC, and mbgw_reply_matches.  Returns its length and *at
 * its offset, or 0: none (yet). */
size_t burst_frame(const uint8_t *req, size_t req_len, const uint8_t *buf, size_t have,
                   int head, int ended, size_t *at);

/* Why a burst that has ended held no frame: -EMSGSIZE it filled cap, -EILSEQ the reply by
 * its start and its length (or silence) but a bad CRC, -EBADMSG anything else. */
long burst_error(const uint8_t *req, const uint8_t *buf, size_t have, int head,
                 size_t cap);

/* --- match.c: a remote line's stream of Modbus TCP frames (remote.c reads it) --- */

/* The first frame from buf[*pos] to buf[have) that answers req (address + PDU) with
 * transaction id tid, see mbgw_remote_exchange: returns its length, at buf[*pos].  Whole
 * frames before it that do not answer are skipped (*pos past them, *strays counted).  0:
 * none is whole yet (*pos at the frame begun, if any); -EPROTO the header at *pos frames
 * nothing. */
long mbap_cut(const uint8_t *req, size_t req_len, unsigned tid, const uint8_t *buf,
              size_t have, size_t *pos, int *strays);

/* --- tty.c --- */

/* Raise (on) or drop RTS. */
int tty_set_rts(int fd, int on);

#endif
