/* The MBAP header of Modbus TCP (Messaging on TCP/IP Implementation Guide V1.0b, 3.1.3):
 * the one rule for which headers frame a request or a reply, for the shortcut
 * (forward.c), the table's server (table_answer.c) and the Python side's framing. */
#include <errno.h>

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
