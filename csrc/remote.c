/* A remote line's exchange on Modbus TCP in one call (slave mode, `connect =
 * "modbus-tcp://..."`): the request out in one send with our own transaction id, then
 * the socket read until match.c's mbap_cut finds the reply in the stream.  The socket is
 * the caller's: connected, opened and closed by it. */
#include <errno.h>
#include <sched.h>
#include <stdint.h>
#include <string.h>
#include <sys/socket.h>

#include "internal.h"
#include "mbgw.h"

/* recv() of what waits on fd, into buf, not waiting.  Returns the bytes, 0 none waits,
 * -ENOTCONN the device closed the connection, another -errno. */
static long recv_some(int fd, uint8_t *buf, size_t cap)
{
    for (;;) {
        ssize_t n = recv(fd, buf, cap, MSG_DONTWAIT);
        if (n > 0)
            return n;
        if (n == 0)
            return -ENOTCONN;
        if (errno == EAGAIN || errno == EWOULDBLOCK)
            return 0;
        if (errno != EINTR)
            return -errno;
    }
}

/* Read and drop what waits on fd (no request is outstanding: none of it is a reply),
 * counting its bytes in *dropped.  Returns 0, or recv_some's negative errno. */
static int drain(int fd, uint8_t *buf, size_t cap, int *dropped)
{
    for (;;) {
        long n = recv_some(fd, buf, cap);
        if (n <= 0)
            return (int)n;
        *dropped += (int)n;
    }
}

/* The request as a Modbus TCP frame in one send; -EAGAIN when the socket took only part
 * of it (the device reads nothing: the connection is of no more use). */
static int send_request(int fd, const uint8_t *req, size_t req_len, unsigned tid)
{
    uint8_t out[MBAP_HEAD_LEN + MBAP_MAX_LENGTH];
    out[0] = (uint8_t)(tid >> 8);
    out[1] = (uint8_t)tid;
    out[2] = out[3] = 0;
    out[4] = (uint8_t)(req_len >> 8);
    out[5] = (uint8_t)req_len;
    memcpy(out + MBAP_HEAD_LEN, req, req_len);
    size_t len = MBAP_HEAD_LEN + req_len;
    for (;;) {
        ssize_t n = send(fd, out, len, MSG_DONTWAIT | MSG_NOSIGNAL);
        if (n == (ssize_t)len)
            return 0;
        if (n >= 0)
            return -EAGAIN;
        if (errno != EINTR)
            return -errno;
    }
}

/* The reply just found (len bytes at frame, MBAP header first) to the client's socket,
 * under the client's transaction id and unit id; the frame is left as it came. */
static int forward_reply(uint8_t *frame, long len, const struct mbgw_forward *to)
{
    uint8_t tid_hi = frame[0], tid_lo = frame[1], unit = frame[MBAP_HEAD_LEN];
    frame[0] = (uint8_t)(to->tid >> 8);
    frame[1] = (uint8_t)to->tid;
    frame[MBAP_HEAD_LEN] = to->unit;
    if (to->in_flight)
        --*to->in_flight;
    ssize_t w;
    do
        w = send(to->fd, frame, (size_t)len, MSG_DONTWAIT | MSG_NOSIGNAL);
    while (w < 0 && errno == EINTR);
    frame[0] = tid_hi;
    frame[1] = tid_lo;
    frame[MBAP_HEAD_LEN] = unit;
    /* all of it when the connection is broken: its next read tells */
    int forwarded = w >= 0 ? (int)w : errno == EAGAIN ? 0 : (int)len;
    if (w > 0 && to->yield_cpu)
        sched_yield();
    return forwarded;
}

int mbgw_remote_send(int fd, uint8_t *buf, size_t cap, const uint8_t *req, size_t req_len,
                     unsigned tid, struct mbgw_remote *r)
{
    memset(r, 0, sizeof *r);
    r->forwarded = -1;
    if (req_len < MBAP_MIN_LENGTH || req_len > MBAP_MAX_LENGTH || cap < MBGW_MBAP_MAX)
        return -EINVAL;
    int err = drain(fd, buf, cap, &r->stale);
    if (err == 0)
        err = send_request(fd, req, req_len, tid & 0xFFFF);
    if (err < 0)
        return err;
    r->sent_ns = now_ns();
    return 0;
}

int mbgw_remote_reply(int fd, uint8_t *buf, size_t cap, const uint8_t *req,
                      size_t req_len, unsigned tid, int64_t deadline_ns,
                      const struct mbgw_forward *to, struct mbgw_remote *r)
{
    size_t have = 0, pos = 0;
    for (;;) {
        long len = mbap_cut(req, req_len, tid & 0xFFFF, buf, have, &pos, &r->strays);
        if (len > 0) {
            r->at = (int)pos;
            r->left = (int)(have - pos - (size_t)len);
            if (to && to->fd >= 0)
                r->forwarded = forward_reply(buf + pos, len, to);
            return (int)len;
        }
        if (len < 0) {
            r->noise = (int)(have - pos);
            r->end_ns = now_ns();
            return (int)len;
        }
        if (pos) { /* room for the rest of the frame that has begun */
            memmove(buf, buf + pos, have - pos);
            have -= pos;
            pos = 0;
        }
        int ready = wait_input(fd, deadline_ns);
        if (ready == 0) {
            r->end_ns = now_ns();
            return -ETIMEDOUT;
        }
        if (ready < 0 && ready != -EIO) { /* -EIO: hang-up or error, which recv tells */
            r->end_ns = now_ns();
            return ready;
        }
        long n = recv_some(fd, buf + have, cap - have);
        if (n < 0 || (n == 0 && ready < 0)) {
            r->end_ns = now_ns();
            return n < 0 ? (int)n : -EIO;
        }
        have += (size_t)n;
        r->received += (int)n;
        r->end_ns = now_ns();
    }
}

int mbgw_remote_exchange(int fd, uint8_t *buf, size_t cap, const uint8_t *req,
                         size_t req_len, unsigned tid, int64_t stout_ns,
                         const struct mbgw_forward *to, struct mbgw_remote *r)
{
    int err = mbgw_remote_send(fd, buf, cap, req, req_len, tid, r);
    if (err < 0)
        return err;
    return mbgw_remote_reply(fd, buf, cap, req, req_len, tid, r->sent_ns + stout_ns, to,
                             r);
}

int mbgw_remote_take(int client_fd, int *in_flight, int line_fd, uint8_t *buf, size_t cap,
                     unsigned tid, struct mbgw_loan *loan, struct mbgw_remote *r)
{
    if (!loan->units || !loan->down)
        return 0;
    uint8_t in[MBAP_HEAD_LEN + MBAP_MAX_LENGTH + 1];
    ssize_t n;
    do
        n = recv(client_fd, in, sizeof in, MSG_PEEK | MSG_DONTWAIT);
    while (n < 0 && errno == EINTR);
    if (n < 0)
        return errno == EWOULDBLOCK ? -EAGAIN : -errno;
    size_t adu_len = loan_request(in, (size_t)n, loan->units, loan->down, loan->adu);
    if (!adu_len)
        return 0; /* it stays in the socket for the face */
    if (mbgw_client_recv(client_fd, in, (size_t)n, &loan->arrived_ns) != n)
        return -EIO; /* what the peek saw is gone: the face reads what is left */
    loan->tid = (uint16_t)be16(in);
    loan->unit = in[MBAP_HEAD_LEN];
    loan->adu_len = (int)adu_len;
    if (in_flight)
        ++*in_flight;
    loan->send_error = mbgw_remote_send(line_fd, buf, cap, loan->adu, adu_len, tid, r);
    return 1;
}
