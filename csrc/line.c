/* Timed I/O on the serial line's fd (opened and configured by libmodbus).  ppoll gives
 * microsecond timeouts where epoll and poll round to milliseconds: at 115200 baud the
 * inter-frame silence is 1.75 ms, so a millisecond lost per transaction would cost
 * ~10 %. */
#define _GNU_SOURCE
#include <errno.h>
#include <poll.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "internal.h"
#include "mbgw.h"

int wait_input(int fd, int64_t until_ns)
{
    for (;;) {
        int64_t left = until_ns - now_ns();
        if (left < 0)
            left = 0; /* time is up: still look once */
        struct timespec ts = { left / 1000000000, left % 1000000000 };
        struct pollfd p = { fd, POLLIN, 0 };
        int rc = ppoll(&p, 1, &ts, NULL);
        if (rc < 0) {
            if (errno == EINTR)
                continue;
            return -errno;
        }
        if (rc == 0)
            return 0;
        if (p.revents & POLLIN)
            return 1;
        return -EIO; /* POLLHUP/POLLERR: the device went away */
    }
}

long read_some(int fd, uint8_t *buf, size_t cap)
{
    for (;;) {
        ssize_t n = read(fd, buf, cap);
        if (n > 0) {
            capture_note(MBGW_CAPTURE_RX, buf, (size_t)n);
            return n;
        }
        if (n == 0)
            return -EIO; /* end of file on a tty: hung up */
        if (errno == EINTR)
            continue;
        if (errno == EAGAIN)
            return 0;
        return -errno;
    }
}

/* The end of a quiet period is spun for rather than slept to: a wake-up from ppoll comes
 * 50 to 120 us late (timer slack, virtual machines), and that is idle line time on every
 * transaction.  Spinning costs at most this much CPU per request. */
#define SPIN_NS 100000

long mbgw_wait_quiet(int fd, int64_t last_ns, int32_t quiet_us)
{
    uint8_t junk[256];
    long discarded = 0;
    for (;;) {
        int64_t until = last_ns + (int64_t)quiet_us * 1000;
        int64_t left = until - now_ns();
        if (left <= 0)
            break;
        int rc = wait_input(fd, left > SPIN_NS ? until - SPIN_NS : now_ns());
        if (rc < 0)
            return rc;
        if (rc == 0)
            continue;
        long n = read_some(fd, junk, sizeof junk);
        if (n < 0)
            return n;
        discarded += n;
        last_ns = now_ns();
    }
    return discarded;
}

int mbgw_idle_wait(int fd, int wake_fd, int timeout_ms)
{
    struct pollfd p[2] = { { wake_fd, POLLIN, 0 }, { fd, POLLIN, 0 } };
    for (;;) {
        int rc = poll(p, 2, timeout_ms);
        if (rc < 0) {
            if (errno == EINTR)
                continue;
            return -errno;
        }
        if (rc == 0)
            return MBGW_IDLE_TIMEOUT;
        if (p[0].revents & POLLIN) {
            uint64_t count;
            if (read(wake_fd, &count, sizeof count) < 0 && errno != EAGAIN)
                return -errno;
            return MBGW_IDLE_WOKEN;
        }
        if (p[1].revents & POLLIN)
            return MBGW_IDLE_INPUT;
        return -EIO;
    }
}

long mbgw_read_reply(int fd, uint8_t *buf, size_t cap, int64_t deadline_ns,
                     int32_t gap_us, int64_t *end_ns)
{
    size_t have = 0;
    *end_ns = 0;
    for (;;) {
        /* The first byte is awaited until the deadline; after it, a silence of gap_us
         * ends the frame, complete or not (Serial Line V1.02 2.5.1.1). */
        int64_t until = have > 0 ? *end_ns + (int64_t)gap_us * 1000 : deadline_ns;
        int rc = wait_input(fd, until);
        if (rc < 0)
            return rc;
        if (rc == 0)
            return have > 0 ? (long)have : -ETIMEDOUT;
        long n = read_some(fd, buf + have, cap - have);
        if (n < 0)
            return n;
        have += (size_t)n;
        *end_ns = now_ns();
        if (have >= cap)
            return (long)have;
    }
}

/* --- slave mode: the reply among what the line carries --- */

/* How many bytes to read now: while the burst may begin with a frame, no further than
 * that frame's end (a frame right behind it is the next call's); else what came. */
static size_t next_read(int head, size_t have, size_t cap)
{
    if (head == 0 && have < MIN_REPLY)
        return MIN_REPLY - have;
    if (head > 0 && (size_t)head > have)
        return (size_t)head - have;
    return cap - have;
}

long mbgw_find_reply(int fd, uint8_t *buf, size_t cap, const uint8_t *req, size_t req_len,
                     int64_t deadline_ns, int32_t gap_us, int64_t *end_ns, int *noise)
{
    size_t have = 0;
    int head = 0; /* burst_head of the bytes read */
    *noise = 0;
    *end_ns = now_ns();
    if (*end_ns >= deadline_ns)
        return -ETIMEDOUT;
    for (;;) {
        /* The first byte is awaited until the deadline; after it, a silence of gap_us
         * ends the burst (Serial Line V1.02 2.5.1.1). */
        long rc =
            wait_input(fd, have > 0 ? *end_ns + (int64_t)gap_us * 1000 : deadline_ns);
        if (rc > 0) {
            rc = read_some(fd, buf + have, next_read(head, have, cap));
            if (rc == 0)
                continue; /* woken without a byte */
        } else if (rc == 0 && have == 0) {
            *end_ns = now_ns();
            return -ETIMEDOUT;
        }
        if (rc < 0) {
            *noise = (int)have;
            return rc;
        }
        if (rc > 0) {
            have += (size_t)rc;
            *end_ns = now_ns();
        }
        int ended = rc == 0 || have == cap;
        head = burst_head(req_len, buf, have);
        size_t at;
        size_t len = burst_frame(req, req_len, buf, have, head, ended, &at);
        if (len > 0) {
            if (at > 0)
                memmove(buf, buf + at, len);
            *noise = (int)(have - len);
            return (long)len;
        }
        if (ended) {
            *noise = (int)have;
            return burst_error(req, buf, have, head, cap);
        }
    }
}

long mbgw_ascii_read_frame(int fd, uint8_t *buf, size_t cap, int64_t deadline_ns,
                           int32_t interchar_us, int64_t *end_ns, int *noise)
{
    /* One character per read: ASCII frames need no silence between them, so the next
     * frame may already be queued behind this one and must stay there. */
    uint8_t chunk[1];
    size_t have = 0;
    long got = 0; /* every byte read */
    long rc;
    if (cap > MBGW_ASCII_MAX_FRAME)
        cap = MBGW_ASCII_MAX_FRAME;
    *end_ns = 0;
    for (;;) {
        int64_t until = deadline_ns;
        if (have > 0 && *end_ns + (int64_t)interchar_us * 1000 < until)
            until = *end_ns + (int64_t)interchar_us * 1000;
        rc = wait_input(fd, until);
        if (rc < 0)
            break;
        if (rc == 0) {
            rc = have > 0 ? -EBADMSG : -ETIMEDOUT;
            break;
        }
        rc = read_some(fd, chunk, sizeof chunk);
        if (rc < 0)
            break;
        got += rc;
        *end_ns = now_ns();
        for (long i = 0; i < rc; i++) {
            uint8_t c = chunk[i];
            if (c == ':')
                have = 0; /* a colon always starts a new frame */
            else if (have == 0)
                continue; /* noise between frames */
            if (have == cap) {
                *noise = (int)got;
                return -EMSGSIZE;
            }
            buf[have++] = c;
            if (c == '\n' && have >= 2 && buf[have - 2] == '\r') {
                *noise = (int)(got - (long)have);
                return (long)have;
            }
        }
    }
    *noise = (int)got;
    return rc;
}

static void sleep_us(int32_t us)
{
    if (us <= 0)
        return;
    struct timespec ts = { us / 1000000, (long)(us % 1000000) * 1000 };
    while (clock_nanosleep(CLOCK_MONOTONIC, 0, &ts, &ts) == EINTR)
        ;
}

int mbgw_write_frame(int fd, const uint8_t *buf, size_t len, int rts_control,
                     int32_t before_us, int32_t after_us)
{
    int rc = 0;
    if (rts_control) {
        if ((rc = tty_set_rts(fd, 1)) < 0)
            return rc;
        sleep_us(before_us);
    }
    size_t done = 0;
    while (done < len) {
        ssize_t n = write(fd, buf + done, len - done);
        if (n > 0) {
            capture_note(MBGW_CAPTURE_TX, buf + done, (size_t)n);
            done += (size_t)n;
            continue;
        }
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0 && errno == EAGAIN) {
            struct pollfd p = { fd, POLLOUT, 0 };
            if (poll(&p, 1, 1000) <= 0 || !(p.revents & POLLOUT)) {
                rc = -EIO;
                goto out;
            }
            continue;
        }
        rc = n < 0 ? -errno : -EIO;
        goto out;
    }
    if (rts_control) {
        if (tcdrain(fd) < 0) {
            rc = -errno;
            goto out;
        }
        sleep_us(after_us);
    }
out:
    /* RTS raised stays raised on no path: a transceiver left transmitting blocks the bus
     * for every device on it until the port is reopened. */
    if (rts_control) {
        int dropped = tty_set_rts(fd, 0);
        if (rc == 0)
            rc = dropped;
    }
    return rc;
}

int mbgw_discard_echo(int fd, const uint8_t *sent, size_t len, int64_t deadline_ns)
{
    uint8_t echo[MBGW_ASCII_MAX_FRAME];
    size_t have = 0;
    while (have < len) {
        int rc = wait_input(fd, deadline_ns);
        if (rc < 0)
            return rc;
        if (rc == 0)
            return -ETIMEDOUT;
        size_t want = len - have;
        long n = read_some(fd, echo + have,
                           want < sizeof echo - have ? want : sizeof echo - have);
        if (n < 0)
            return (int)n;
        have += (size_t)n;
    }
    for (size_t i = 0; i < len; i++)
        if (echo[i] != sent[i])
            return -EPROTO;
    return 0;
}
