/* csrc/request.c: master mode's receive of the serial master's frames, with the tty's
 * reads and waits (line.c) replaced by the input: a stream of bytes, silent gaps at given
 * offsets, and the frame seen last for another slave (whose reply may come).  Input: g
 * (0..3 gaps), g offsets, r (0..7: the length of reply_to), reply_to, then the stream.
 * Rules: each call returns a frame of 4..cap bytes with a valid CRC that the stream held,
 * or -EILSEQ, -EBADMSG, -EMSGSIZE, or -ECANCELED once the stream is used up; each call
 * that does not end the stream takes at least one byte; the buffer is never written past
 * cap (AddressSanitizer). */
#define _GNU_SOURCE /* memmem */
#include <errno.h>
#include <string.h>

#include "internal.h"
#include "mbgw.h"

#include "harness.h"

static const uint8_t *stream;
static size_t stream_len, pos;
static size_t gaps[3];
static size_t n_gaps;

/* The next silence: the first gap at or after pos, else the stream's end. */
static size_t next_gap(void)
{
    size_t end = stream_len;
    for (size_t i = 0; i < n_gaps; i++)
        if (gaps[i] >= pos && gaps[i] < end)
            end = gaps[i];
    return end;
}

/* A gap is silence once: crossing it removes it. */
static void cross_gap(void)
{
    for (size_t i = 0; i < n_gaps; i++)
        if (gaps[i] == pos)
            gaps[i] = (size_t)-1;
}

int wait_input(int fd, int64_t until_ns)
{
    (void)fd;
    (void)until_ns;
    if (pos < next_gap())
        return 1;
    cross_gap();
    return 0;
}

long read_some(int fd, uint8_t *buf, size_t cap)
{
    (void)fd;
    size_t n = next_gap() - pos;
    if (n > cap)
        n = cap;
    memcpy(buf, stream + pos, n);
    pos += n;
    return (long)n;
}

int mbgw_idle_wait(int fd, int wake_fd, int timeout_ms)
{
    (void)fd;
    (void)wake_fd;
    (void)timeout_ms;
    cross_gap();
    return pos < stream_len ? MBGW_IDLE_INPUT : MBGW_IDLE_WOKEN;
}

static void one(const uint8_t *data, size_t len)
{
    if (len < 2)
        return;
    n_gaps = data[0] % 4;
    size_t at = 1;
    if (len < at + n_gaps + 1)
        return;
    for (size_t i = 0; i < n_gaps; i++)
        gaps[i] = data[at++];
    size_t reply_to_len = data[at++] % 8;
    if (len < at + reply_to_len)
        return;
    uint8_t *reply_to = exact_copy(data + at, reply_to_len);
    at += reply_to_len;
    stream = data + at;
    stream_len = len - at;
    pos = 0;

    uint8_t *buf = malloc(MBGW_RTU_MAX_ADU);
    MUST(buf != NULL);
    for (;;) {
        size_t before = pos;
        long n = mbgw_rtu_read_request(0, -1, buf, MBGW_RTU_MAX_ADU, reply_to,
                                       reply_to_len, 1750, -1);
        if (n == -ECANCELED) {
            MUST(pos == stream_len);
            break;
        }
        MUST(pos > before);
        if (n > 0) {
            MUST(n >= 4 && n <= MBGW_RTU_MAX_ADU && (size_t)n <= pos - before);
            MUST(mbgw_crc16(buf, (size_t)n) == 0);
            MUST(memmem(stream + before, pos - before, buf, (size_t)n) != NULL);
        } else {
            MUST(n == -EILSEQ || n == -EBADMSG || n == -EMSGSIZE);
        }
    }
    free(buf);
    free(reply_to);
}
