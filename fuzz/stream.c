/* csrc/match.c's mbap_cut: a remote line's reply among the Modbus TCP frames of a stream.
 * Input: the request's length n (2..65), the request (address + PDU), our transaction id
 * (2 bytes, big-endian), a piece size p (1..16), then the bytes the device's socket
 * brought, read p at a time as mbgw_remote_exchange reads them (what is cut is moved to
 * the front before the next read).
 * Rules: a frame taken lies inside what was read, has our tid, protocol id 0, its MBAP
 * length, the request's address as its unit id and a PDU that mbgw_reply_matches; the
 * frames skipped before it are whole; -EPROTO only for a header that frames nothing; the
 * same reply, strays and rest whether the stream comes in pieces or whole (a frame's
 * worth at once); no byte past what was read is looked at (AddressSanitizer). */
#include <errno.h>
#include <string.h>

#include "internal.h"
#include "mbgw.h"

#include "harness.h"

struct outcome {
    long len;        /* mbap_cut's last return */
    size_t consumed; /* the stream's bytes before the reply (or before where it ended) */
    int strays;
    uint8_t reply[300]; /* the reply taken, if one was */
};

/* Feed stream[0..len) p bytes at a time to mbap_cut as remote.c does. */
static void cut(const uint8_t *req, size_t req_len, unsigned tid, const uint8_t *stream,
                size_t len, size_t p, struct outcome *o)
{
    uint8_t buf[MBGW_MBAP_MAX * 2];
    size_t have = 0, pos = 0, fed = 0, dropped = 0;
    memset(o, 0, sizeof *o);
    for (;;) {
        uint8_t *piece = exact_copy(buf, have);
        size_t before = pos;
        o->len = mbap_cut(req, req_len, tid, piece, have, &pos, &o->strays);
        MUST(pos >= before && pos <= have);
        if (o->len > 0) {
            MUST((size_t)o->len >= MBAP_LEN + 1 && pos + (size_t)o->len <= have);
            memcpy(o->reply, piece + pos, (size_t)o->len);
        }
        free(piece);
        if (o->len != 0 || fed == len)
            break;
        memmove(buf, buf + pos, have - pos);
        have -= pos;
        dropped += pos;
        pos = 0;
        size_t n = len - fed < p ? len - fed : p;
        MUST(have + n <= sizeof buf);
        memcpy(buf + have, stream + fed, n);
        have += n;
        fed += n;
    }
    o->consumed = dropped + pos;
}

static void one(const uint8_t *data, size_t len)
{
    if (len < 1)
        return;
    size_t req_len = 2 + data[0] % 64;
    if (len < 1 + req_len + 3)
        return;
    uint8_t *req = exact_copy(data + 1, req_len);
    unsigned tid = (unsigned)data[1 + req_len] << 8 | data[2 + req_len];
    size_t p = 1 + data[3 + req_len] % 16;
    const uint8_t *stream = data + 4 + req_len;
    size_t stream_len = len - 4 - req_len;

    struct outcome pieces, whole;
    cut(req, req_len, tid, stream, stream_len, p, &pieces);
    cut(req, req_len, tid, stream, stream_len, MBGW_MBAP_MAX, &whole);

    MUST(pieces.len > 0 || pieces.len == 0 || pieces.len == -EPROTO);
    MUST(pieces.len == whole.len && pieces.strays == whole.strays);
    MUST(pieces.consumed == whole.consumed);
    if (pieces.len > 0) {
        const uint8_t *f = pieces.reply;
        MUST(memcmp(f, whole.reply, (size_t)pieces.len) == 0);
        MUST(((unsigned)f[0] << 8 | f[1]) == tid && f[2] == 0 && f[3] == 0);
        MUST(MBAP_HEAD_LEN + ((unsigned)f[4] << 8 | f[5]) == (unsigned)pieces.len);
        MUST(f[MBAP_HEAD_LEN] == req[0]);
        MUST(mbgw_reply_matches(req + 1, req_len - 1, f + MBAP_LEN,
                                (size_t)pieces.len - MBAP_LEN));
    } else if (pieces.len == -EPROTO) {
        const uint8_t *h = stream + pieces.consumed;
        MUST(pieces.consumed + MBAP_LEN <= stream_len);
        MUST(mbgw_mbap_frame_len(be16(h + 2), be16(h + 4)) < 0);
    }
    free(req);
}
