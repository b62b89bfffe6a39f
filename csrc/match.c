/* Does a reply answer its request (either mode), and where is the reply among the bytes a
 * burst on the line brought, or a remote line's stream of Modbus TCP frames (slave mode).
 * No I/O: line.c and remote.c read, this file judges. */
#include <errno.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "internal.h"
#include "mbgw.h"

#define NO_FRAME (-2) /* burst_head: no frame starts here */

static unsigned quantity(const uint8_t *req)
{
    return (unsigned)req[3] << 8 | req[4];
}

int mbgw_reply_matches(const uint8_t *req, size_t req_len, const uint8_t *rsp,
                       size_t rsp_len)
{
    if (req_len < 1 || rsp_len < 1)
        return 0;
    uint8_t fc = req[0];
    if (rsp[0] == (fc | 0x80))
        return rsp_len == 2;
    if (rsp[0] != fc)
        return 0;
    switch (fc) {
    case 0x01:
    case 0x02:
        if (req_len < 5)
            return 1;
        return rsp_len >= 2 && rsp[1] == (quantity(req) + 7) / 8 &&
               rsp_len == 2u + rsp[1];
    case 0x03:
    case 0x04:
    case 0x17:
        if (req_len < 5)
            return 1;
        return rsp_len >= 2 && rsp[1] == 2 * quantity(req) && rsp_len == 2u + rsp[1];
    case 0x05:
    case 0x06:
    case 0x0F:
    case 0x10:
        return rsp_len == 5 && req_len >= 5 && memcmp(rsp + 1, req + 1, 4) == 0;
    case 0x16:
        return rsp_len == req_len && memcmp(rsp, req, req_len) == 0;
    default:
        return 1;
    }
}

int mbgw_tcp_reply_verdict(const uint8_t *req, size_t req_len, uint8_t unit,
                           uint8_t rsp_unit, const uint8_t *rsp, size_t rsp_len)
{
    uint8_t adu[MBGW_RTU_MAX_ADU]; /* the reply as an RTU ADU, to read its own length */
    if (rsp_len < 1 || rsp_len + 1 + CRC_LEN > sizeof adu)
        return MBGW_REPLY_BAD_LENGTH;
    adu[0] = rsp_unit;
    memcpy(adu + 1, rsp, rsp_len);
    int own = mbgw_rtu_reply_length(req_len + 1, adu, rsp_len + 1);
    if (own != MBGW_LEN_UNKNOWN && own != (int)(rsp_len + 1 + CRC_LEN))
        return MBGW_REPLY_BAD_LENGTH;
    if (rsp_unit != unit)
        return MBGW_REPLY_WRONG_UNIT;
    if (!mbgw_reply_matches(req, req_len, rsp, rsp_len))
        return MBGW_REPLY_WRONG_FUNCTION;
    return MBGW_REPLY_ANSWERS;
}

/* --- slave mode: the reply among the bytes of a burst --- */

int burst_head(size_t req_len, const uint8_t *f, size_t have)
{
    int len = mbgw_rtu_reply_length(req_len, f, have);
    if (len > 0 && (len < MIN_FRAME || len > MBGW_RTU_MAX_ADU))
        return NO_FRAME;
    return len;
}

/* The length of the frame with a valid CRC at f, of length len (burst_head's, ended: the
 * burst is over, so a frame that silence ends ends here), or 0: none. */
static size_t whole_frame(const uint8_t *f, size_t have, int len, int ended)
{
    if (len == MBGW_LEN_UNKNOWN && ended)
        len = have > MBGW_RTU_MAX_ADU ? 0 : (int)have;
    if (len < MIN_FRAME || (size_t)len > have)
        return 0;
    return mbgw_crc16(f, (size_t)len) == 0 ? (size_t)len : 0;
}

/* f starts as the reply to req would: req's address, its function or that exception. */
static int starts_reply(const uint8_t *req, const uint8_t *f)
{
    return f[0] == req[0] && (f[1] == req[1] || f[1] == (req[1] | 0x80));
}

/* The reply to req inside buf[1..have): a frame that starts as the reply, has a valid CRC
 * and answers req (mbgw_reply_matches).  Returns its length and *at its offset, or 0. */
static size_t reply_inside(const uint8_t *req, size_t req_len, const uint8_t *buf,
                           size_t have, int ended, size_t *at)
{
    for (size_t i = 1; i + MIN_REPLY <= have; i++) {
        const uint8_t *f = buf + i;
        if (!starts_reply(req, f))
            continue;
        size_t len = whole_frame(f, have - i, burst_head(req_len, f, have - i), ended);
        if (len && mbgw_reply_matches(req + 1, req_len - 1, f + 1, len - 1 - CRC_LEN)) {
            *at = i;
            return len;
        }
    }
    return 0;
}

size_t burst_frame(const uint8_t *req, size_t req_len, const uint8_t *buf, size_t have,
                   int head, int ended, size_t *at)
{
    *at = 0;
    size_t len = whole_frame(buf, have, head, ended);
    return len ? len : reply_inside(req, req_len, buf, have, ended, at);
}

long burst_error(const uint8_t *req, const uint8_t *buf, size_t have, int head,
                 size_t cap)
{
    if (have == cap)
        return -EMSGSIZE;
    if (have >= 2 && starts_reply(req, buf) &&
        (head == MBGW_LEN_UNKNOWN || (head > 0 && (size_t)head <= have)))
        return -EILSEQ;
    return -EBADMSG;
}

/* --- slave mode: the reply among a remote line's Modbus TCP frames --- */

long mbap_cut(const uint8_t *req, size_t req_len, unsigned tid, const uint8_t *buf,
              size_t have, size_t *pos, int *strays)
{
    while (have - *pos >= MBAP_LEN) {
        const uint8_t *f = buf + *pos;
        int end = mbgw_mbap_frame_len(be16(f + 2), be16(f + 4));
        if (end < 0)
            return -EPROTO;
        if (have - *pos < (size_t)end)
            return 0;
        if (be16(f) == tid && req_len >= 2 &&
            mbgw_tcp_reply_verdict(req + 1, req_len - 1, req[0], f[MBAP_HEAD_LEN],
                                   f + MBAP_LEN,
                                   (size_t)end - MBAP_LEN) == MBGW_REPLY_ANSWERS)
            return end;
        *pos += (size_t)end;
        ++*strays;
    }
    return 0;
}
