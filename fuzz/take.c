/* csrc/mbap.c's loan_request: whether what a lent client sent is one request its line
 * takes, and the request as it goes on the line.
 * Input: a unit id u, an address a, a down flag d (its low bit), then the bytes the
 * client's socket held; the line maps u to a (0: no unit is the line's) and marks a down
 * when d. Rules: taken only when the bytes are exactly one frame whose MBAP header frames
 * them (mbgw_mbap_frame_len), whose unit id is u, a not 0 and not down; then the request
 * is a followed by the frame's PDU, its length the header's; no byte past what came is
 * looked at, nor written past the request (AddressSanitizer). */
#include <string.h>

#include "internal.h"
#include "mbgw.h"

#include "harness.h"

static void one(const uint8_t *data, size_t len)
{
    if (len < 4) /* a byte at least to judge */
        return;
    uint8_t units[256] = { 0 }, down[256] = { 0 };
    uint8_t unit = data[0], address = data[1];
    units[unit] = address;
    down[address] = data[2] & 1;
    size_t n = len - 3;
    uint8_t *in = exact_copy(data + 3, n);
    uint8_t *adu = malloc(MBAP_MAX_LENGTH);
    MUST(adu != NULL);
    size_t got = loan_request(in, n, units, down, adu);
    int frames =
        n >= MBAP_LEN && mbgw_mbap_frame_len(be16(in + 2), be16(in + 4)) == (int)n;
    int ours = n >= MBAP_LEN && in[MBAP_HEAD_LEN] == unit && address && !(data[2] & 1);
    MUST(!got == !(frames && ours));
    if (got) {
        MUST(got == be16(in + 4) && got >= MBAP_MIN_LENGTH && got <= MBAP_MAX_LENGTH);
        MUST(adu[0] == address && memcmp(adu + 1, in + MBAP_LEN, got - 1) == 0);
    }
    free(adu);
    free(in);
}
