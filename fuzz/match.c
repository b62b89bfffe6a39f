/* csrc/match.c: does a reply answer its request, and where is it in a burst.  Input: the
 * request's length n (2..65), the request (address + PDU), the unit byte mbgw sent, then
 * the bytes the line (or the server) brought.
 * Rules: mbgw_reply_matches is 0 or 1, an exception reply matches only as 2 bytes;
 * mbgw_tcp_reply_verdict answers only when the unit is the one sent and the PDU matches;
 * a frame taken from a burst, at each prefix as line.c reads it, lies inside what was
 * read, is at least 4 bytes with a valid CRC, and one found behind noise is req's address
 * and matches req; a burst with no frame has one of the three errors; no byte past what
 * was read is looked at (AddressSanitizer). */
#include <errno.h>

#include "internal.h"
#include "mbgw.h"

#include "harness.h"

static void one(const uint8_t *data, size_t len)
{
    if (len < 2)
        return;
    size_t req_len = 2 + data[0] % 64;
    if (len < 2 + req_len)
        return;
    uint8_t *req = exact_copy(data + 1, req_len);
    uint8_t unit = data[1 + req_len];
    const uint8_t *rest = data + 2 + req_len;
    size_t rest_len = len - 2 - req_len;

    /* The rest as a reply PDU (TCP: unit id first, then the PDU). */
    if (rest_len >= 1) {
        uint8_t *rsp = exact_copy(rest + 1, rest_len - 1);
        int matches = mbgw_reply_matches(req + 1, req_len - 1, rsp, rest_len - 1);
        MUST(matches == 0 || matches == 1);
        if (matches && rest_len - 1 >= 1 && rsp[0] == (req[1] | 0x80) && rsp[0] != req[1])
            MUST(rest_len - 1 == 2);
        int verdict = mbgw_tcp_reply_verdict(req + 1, req_len - 1, unit, rest[0], rsp,
                                             rest_len - 1);
        MUST(verdict >= MBGW_REPLY_ANSWERS && verdict <= MBGW_REPLY_WRONG_FUNCTION);
        if (verdict == MBGW_REPLY_ANSWERS)
            MUST(rest[0] == unit && matches);
        free(rsp);
    }

    /* The rest as a burst on the line, read as mbgw_find_reply reads it. */
    size_t cap = rest_len < MBGW_REPLY_SCAN ? rest_len : MBGW_REPLY_SCAN;
    for (size_t have = 1; have <= cap; have++) {
        uint8_t *buf = exact_copy(rest, have);
        int ended = have == cap;
        int head = burst_head(req_len, buf, have);
        size_t at = 0;
        size_t frame = burst_frame(req, req_len, buf, have, head, ended, &at);
        if (frame) {
            MUST(frame >= 4 && at + frame <= have);
            MUST(mbgw_crc16(buf + at, frame) == 0);
            if (at > 0) {
                MUST(buf[at] == req[0]);
                MUST(mbgw_reply_matches(req + 1, req_len - 1, buf + at + 1, frame - 3));
            }
        } else if (ended) {
            long err = burst_error(req, buf, have, head, cap);
            MUST(err == -EMSGSIZE || err == -EILSEQ || err == -EBADMSG);
        }
        free(buf);
        if (frame)
            break;
    }
    free(req);
}
