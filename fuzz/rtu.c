/* csrc/rtu.c: the RTU length of a request and of a reply, judged from each prefix of a
 * frame.  Rules: the answer is 0 (more bytes needed), MBGW_LEN_UNKNOWN or a length that
 * holds at least the bytes it was judged from (address, function code, what was read);
 * once known it never changes as more bytes come (request.c reads up to it, then stops);
 * no byte past the prefix is read (AddressSanitizer).  Input: the request's length (2 +
 * the byte % 253), then the frame. */
#include "internal.h"
#include "mbgw.h"

#include "harness.h"

static void stable(int (*length)(size_t, const uint8_t *, size_t), size_t req_len,
                   const uint8_t *frame, size_t len)
{
    int known = 0;
    for (size_t have = 0; have <= len; have++) {
        uint8_t *prefix = exact_copy(frame, have);
        int n = length(req_len, prefix, have);
        free(prefix);
        MUST(n == 0 || n == MBGW_LEN_UNKNOWN || n >= 4);
        MUST(have >= 2 || n == 0);
        if (known != 0)
            MUST(n == known);
        known = n;
    }
}

static int request_length(size_t req_len, const uint8_t *req, size_t have)
{
    (void)req_len;
    return mbgw_rtu_request_length(req, have);
}

static void one(const uint8_t *data, size_t len)
{
    if (len < 1)
        return;
    /* an ADU without CRC: 2..254 */
    size_t req_len = 2 + data[0] % (MBGW_RTU_MAX_ADU - 3);
    stable(request_length, 0, data + 1, len - 1);
    stable(mbgw_rtu_reply_length, req_len, data + 1, len - 1);
}
