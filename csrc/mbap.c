/* The MBAP header of Modbus TCP (Messaging on TCP/IP Implementation Guide V1.0b, 3.1.3):
 * the one rule for which headers frame a request or a reply, for the shortcut
 * (forward.c), the table's server (table_answer.c), a lent client's request (remote.c)
 * and the Python side's framing. */
#include <errno.h>
#include <string.h>

#include "internal.h"
#include "mbgw.h"

int mbgw_mbap_frame_len(unsigned protocol, unsigned length)
{
    if (protocol != 0)
        return -EPROTO;
    if (length < MBAP_MIN_LENGTH || length > MBAP_MAX_LENGTH)
        return -EMSGSIZE;
    return MBAP_HEAD_LEN + (int)length;
}

size_t loan_request(const uint8_t *in, size_t n, const uint8_t *units,
                    const uint8_t *down, uint8_t *adu)
{
    /* exactly one whole request: a header that frames what came, no more, no less */
    if (n < MBAP_LEN || mbgw_mbap_frame_len(be16(in + 2), be16(in + 4)) != (int)n)
        return 0;
    uint8_t address = units[in[MBAP_HEAD_LEN]];
    if (!address || down[address])
        return 0;
    size_t adu_len = be16(in + 4);
    adu[0] = address;
    memcpy(adu + 1, in + MBAP_LEN, adu_len - 1);
    return adu_len;
}
