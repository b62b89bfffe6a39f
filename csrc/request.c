/* Master mode's serial receive: every frame the serial master puts on the line, whatever
 * its address.  libmodbus 3.1.6 serves one address (modbus-rtu.c's
 * _modbus_rtu_check_integrity drops the frames for others), and takes the frame after a
 * request for another slave for that slave's reply even when it is the next request.
 *
 * RTU frames carry no length, so the end of a frame is found from its content (Modbus
 * over Serial Line V1.02, 2.5.1: the receiver checks the CRC, then the address):
 * - the length of a request with its function code (mbgw_rtu_request_length);
 * - for a frame from the slave the previous request was for, also the length of that
 *   slave's reply (mbgw_rtu_reply_length): on a shared bus the answer of a slave mbgw
 *   does not stand for comes next;
 * - the first of these lengths at which the CRC checks ends the frame; when none does, or
 *   the function code has no known length, the frame ends with gap_us of silence.
 * Bytes are read no further than the next possible end, so a frame that follows at once
 * (the other slave's reply, or a burst written in one go) stays in the kernel's queue for
 * the next call and no state is kept between calls.  Noise before a frame (a glitch as a
 * transceiver turns around) spoils the first of these lengths: when the burst that
 * silence ends has no valid CRC, the frame is looked for at its end, behind the noise.
 */
#include <errno.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "internal.h"
#include "mbgw.h"

#define HEADER 2 /* address and function code: what every length is computed from */

/* Wait up to gap_us for more input.  1 input, 0 silence, -errno on error or hang-up. */
static int wait_gap(int fd, int32_t gap_us)
{
    return wait_input(fd, now_ns() + (int64_t)gap_us * 1000);
}

/* A possible end of frame: > 0 the length, 0 more bytes are needed to tell, -1 none. */
static int end_candidate(int len, size_t cap)
{
    if (len == 0)
        return 0;
    if (len < MIN_FRAME || (size_t)len > cap)
        return -1;
    return len;
}

/* How many bytes may be read now without passing a possible end of frame. */
static size_t next_read(const int *ends, int n, size_t have, size_t cap)
{
    size_t want = cap - have; /* none left: read until silence */
    for (int i = 0; i < n; i++) {
        size_t limit;
        if (ends[i] == 0)
            limit = have < HEADER ? HEADER - have : 1;
        else if (ends[i] > 0 && (size_t)ends[i] > have)
            limit = (size_t)ends[i] - have;
        else
            continue;
        if (limit < want)
            want = limit;
    }
    return want;
}

/* The frame at the end of a burst of have bytes that fails its CRC, behind noise: from
 * the first offset at which the rest has a valid CRC and is a frame by length (a
 * request's, or the reply to reply_to's) or one that only silence ends.  Moved to buf[0];
 * 0 when none. */
static size_t frame_behind_noise(uint8_t *buf, size_t have, const uint8_t *reply_to,
                                 size_t reply_to_len)
{
    for (size_t at = 1; at + MIN_FRAME <= have; at++) {
        uint8_t *f = buf + at;
        int len = (int)(have - at);
        int request = mbgw_rtu_request_length(f, (size_t)len);
        int reply = reply_to_len > 0 && f[0] == reply_to[0]
                        ? mbgw_rtu_reply_length(reply_to_len, f, (size_t)len)
                        : 0;
        if ((request == len || request == MBGW_LEN_UNKNOWN || reply == len) &&
            mbgw_crc16(f, (size_t)len) == 0) {
            memmove(buf, f, (size_t)len);
            return (size_t)len;
        }
    }
    return 0;
}

/* Skip input until gap_us of silence. */
static long skip_frame(int fd, int32_t gap_us)
{
    uint8_t junk[64];
    for (;;) {
        int rc = wait_gap(fd, gap_us);
        if (rc <= 0)
            return rc;
        long n = read_some(fd, junk, sizeof junk);
        if (n < 0)
            return n;
    }
}

/*
 * long mbgw_rtu_read_request(fd, wake_fd, buf, cap, reply_to, reply_to_len, gap_us,
 *                            idle_ms)
 *
 * Description: waits up to idle_ms (-1: no limit) for a frame on fd, then reads that one
 * frame into buf (cap should be MBGW_RTU_MAX_ADU).  reply_to (reply_to_len bytes, CRC
 * excluded) is the frame seen last for an address mbgw does not answer for, whose reply
 * may come now; reply_to_len 0 when there is none.  gap_us is the end-of-frame silence
 * (t3.5 or the configured silence); a longer gap inside a frame ends it (incomplete
 * frames are dropped).
 *
 * Returns: the frame's length, CRC included (at least 4; the CRC is valid).
 *
 * Errors: -ECANCELED wake_fd (an eventfd) was signalled, or idle_ms passed, before a
 * frame began (so that the caller's loop turns: systemd's watchdog); -EILSEQ the frame
 * ended by silence with a bad CRC; -EBADMSG it was shorter than 4 bytes; -EMSGSIZE it was
 * longer than cap (the rest was skipped); -EIO the device hung up; other -errno.
 */
long mbgw_rtu_read_request(int fd, int wake_fd, uint8_t *buf, size_t cap,
                           const uint8_t *reply_to, size_t reply_to_len, int32_t gap_us,
                           int idle_ms)
{
    size_t have = 0;
    int ends[2] = { 0, -1 }; /* as a request; as the awaited reply */
    for (;;) {
        int rc = have == 0 ? mbgw_idle_wait(fd, wake_fd, idle_ms) : wait_gap(fd, gap_us);
        if (rc < 0)
            return rc;
        if (have == 0 && rc != MBGW_IDLE_INPUT) /* woken, or idle_ms without input */
            return -ECANCELED;
        if (rc == 0) { /* silence: the frame is over */
            if (have < MIN_FRAME)
                return -EBADMSG;
            if (mbgw_crc16(buf, have) == 0)
                return (long)have;
            size_t len = frame_behind_noise(buf, have, reply_to, reply_to_len);
            return len > 0 ? (long)len : -EILSEQ;
        }
        long n = read_some(fd, buf + have, next_read(ends, 2, have, cap));
        if (n < 0)
            return n;
        if (n == 0)
            continue; /* woken without a byte */
        have += (size_t)n;

        ends[0] = end_candidate(mbgw_rtu_request_length(buf, have), cap);
        if (reply_to_len > 0 && buf[0] == reply_to[0])
            ends[1] = end_candidate(mbgw_rtu_reply_length(reply_to_len, buf, have), cap);
        if ((ends[0] == (int)have || ends[1] == (int)have) && mbgw_crc16(buf, have) == 0)
            return (long)have;
        if (have == cap) {
            if (mbgw_crc16(buf, have) == 0)
                return (long)have;
            long skipped = skip_frame(fd, gap_us);
            return skipped < 0 ? skipped : -EMSGSIZE;
        }
    }
}
