/* Slave mode's quick ways between a client's socket and the line, before Python sees
 * anything: a reply that answers goes to the client's socket (mbgw_receive_reply,
 * mbgw_exchange), and a request that finds the line idle goes on it (mbgw_take_request).
 * Whether a reply answers is match.c's to say.  And the read of a client's socket that
 * tells when what it read arrived (mbgw_client_recv), for the line's order. */
#include <errno.h>
#include <sched.h>
#include <stdint.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/uio.h>

#include <modbus.h>

#include "internal.h"
#include "mbgw.h"

/* An MBAP header's first bytes, then the ADU: its address where the unit id goes. */
_Static_assert(MBGW_REPLY_AT == MBAP_HEAD_LEN, "MBGW_REPLY_AT is MBAP_HEAD_LEN");

int mbgw_stamp_arrivals(int fd)
{
    int on = 1;
    return setsockopt(fd, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof on) < 0 ? -errno : 0;
}

/* The wall clock's lead over the monotonic clock, from readings close together: one read
 * between two of the other, again when something ran in between. */
static int64_t wall_lead_ns(void)
{
    int64_t lead = 0;
    for (int tries = 0; tries < 3; tries++) {
        struct timespec real;
        int64_t before = now_ns();
        clock_gettime(CLOCK_REALTIME, &real);
        int64_t after = now_ns();
        lead = (int64_t)real.tv_sec * 1000000000 + real.tv_nsec - (before + after) / 2;
        if (after - before < 2000)
            break;
    }
    return lead;
}

/* The kernel's receive timestamp (CLOCK_REALTIME, of the newest segment the read took) on
 * the monotonic clock, never after now; now when there is none (a socket without
 * SO_TIMESTAMPNS, data that came before the first socket asked for timestamps).  A step
 * of the wall clock between the arrival and the read moves the arrival by as much. */
static int64_t arrival_ns(struct msghdr *msg)
{
    int64_t now = now_ns();
    for (struct cmsghdr *c = CMSG_FIRSTHDR(msg); c; c = CMSG_NXTHDR(msg, c)) {
        if (c->cmsg_level != SOL_SOCKET || c->cmsg_type != SCM_TIMESTAMPNS)
            continue;
        struct timespec stamp;
        memcpy(&stamp, CMSG_DATA(c), sizeof stamp);
        int64_t arrived =
            (int64_t)stamp.tv_sec * 1000000000 + stamp.tv_nsec - wall_lead_ns();
        return arrived < now ? arrived : now;
    }
    return now;
}

long mbgw_client_recv(int fd, uint8_t *buf, size_t cap, int64_t *arrived_ns)
{
    struct iovec iov = { buf, cap };
    union {
        struct cmsghdr align;
        char space[CMSG_SPACE(sizeof(struct timespec))];
    } control;
    struct msghdr msg = { .msg_iov = &iov,
                          .msg_iovlen = 1,
                          .msg_control = control.space,
                          .msg_controllen = sizeof control.space };
    ssize_t n;
    do
        n = recvmsg(fd, &msg, MSG_DONTWAIT);
    while (n < 0 && errno == EINTR);
    if (n < 0)
        return errno == EWOULDBLOCK ? -EAGAIN : -errno;
    *arrived_ns = arrival_ns(&msg);
    return n;
}

int mbgw_receive_reply(modbus_t *ctx, uint8_t *buf, const uint8_t *req, size_t req_len,
                       int64_t deadline_ns, int32_t gap_us, const struct mbgw_forward *to,
                       int64_t *end_ns, int *forwarded, int *noise)
{
    *forwarded = -1;
    int fd = modbus_get_socket(ctx);
    if (fd < 0) { /* no line open: ppoll would ignore the fd and wait for the deadline */
        *noise = 0;
        *end_ns = now_ns();
        return -EBADF;
    }
    uint8_t *adu = buf + MBGW_REPLY_AT;
    int n = (int)mbgw_find_reply(fd, adu, MBGW_REPLY_SCAN, req, req_len, deadline_ns,
                                 gap_us, end_ns, noise);
    if (n < 0 || adu[0] != req[0] || to->fd < 0 || *end_ns > deadline_ns)
        return n;
    size_t pdu_len = (size_t)n - 1 - CRC_LEN;
    if (!mbgw_reply_matches(req + 1, req_len - 1, adu + 1, pdu_len))
        return n;
    /* MBAP header: transaction id, protocol 0, length (unit id + PDU), unit id */
    uint8_t address = adu[0];
    buf[0] = to->tid >> 8;
    buf[1] = to->tid & 0xff;
    buf[2] = buf[3] = 0;
    buf[4] = (pdu_len + 1) >> 8;
    buf[5] = (pdu_len + 1) & 0xff;
    adu[0] = to->unit;
    if (to->in_flight)
        --*to->in_flight;
    ssize_t w =
        send(to->fd, buf, MBGW_REPLY_AT + 1 + pdu_len, MSG_DONTWAIT | MSG_NOSIGNAL);
    adu[0] = address;
    if (w >= 0)
        *forwarded = (int)w;
    else
        *forwarded = errno == EAGAIN ? 0 : (int)(MBGW_REPLY_AT + 1 + pdu_len);
    /* The client just woken is often on this CPU: let it run before our bookkeeping. */
    if (w > 0 && to->yield_cpu)
        sched_yield();
    return n;
}

int mbgw_exchange(modbus_t *ctx, uint8_t *buf, const uint8_t *req, size_t req_len,
                  int64_t char_ns, int64_t stout_ns, int32_t gap_us,
                  const struct mbgw_forward *to, int64_t *times, int *forwarded,
                  int *noise)
{
    *forwarded = -1;
    *noise = 0;
    if (mbgw_send_rtu(ctx, req, req_len) < 0) {
        times[0] = 0; /* nothing left */
        times[1] = now_ns();
        return -errno;
    }
    times[0] = now_ns() + (int64_t)(req_len + CRC_LEN) * char_ns;
    return mbgw_receive_reply(ctx, buf, req, req_len, times[0] + stout_ns, gap_us, to,
                              &times[1], forwarded, noise);
}

int mbgw_take_request(modbus_t *ctx, int client_fd, int *in_flight, uint8_t *in,
                      size_t in_cap, uint8_t *buf, struct mbgw_shortcut *sc)
{
    sc->taken = 0;
    long n = mbgw_client_recv(client_fd, in, in_cap, &sc->arrived_ns);
    if (n < 0)
        return (int)n;
    if (n < MBAP_LEN)
        return (int)n;
    /* MBAP header: transaction id, protocol id, length (unit id + PDU), unit id */
    unsigned length = (unsigned)in[4] << 8 | in[5];
    if (mbgw_mbap_frame_len((unsigned)in[2] << 8 | in[3], length) != n)
        return (int)n; /* a bad header, or not exactly one request */
    uint8_t unit = in[6];
    uint8_t address = sc->slaveid ? sc->slaveid : unit;
    /* a down address: Python refuses the request at once, or sends it as the probe;
     * one in its late window waits in the queue (the late reply would look like its
     * answer); one with timing of its own (stout, pause) is sent by Python, which keeps
     * it */
    int64_t now = now_ns();
    if (address < 1 || address > MBGW_MAX_ADDRESS || !sc->framed[in[7]] ||
        sc->down[address] || (sc->own && sc->own[address]) || now < sc->quiet_until_ns ||
        now < sc->late_until[address])
        return (int)n;
    uint8_t adu[MBGW_RTU_MAX_ADU];
    adu[0] = sc->address = address;
    memcpy(adu + 1, in + MBAP_LEN, length - 1);
    struct mbgw_forward to = { client_fd, (uint16_t)(in[0] << 8 | in[1]), unit, 1,
                               in_flight };
    sc->taken = 1;
    sc->result = mbgw_exchange(ctx, buf, adu, length, sc->char_ns, sc->stout_ns,
                               sc->gap_us, &to, sc->times, &sc->forwarded, &sc->noise);
    return (int)n;
}
