/* RTU frame lengths for every public function code (Modbus Application Protocol V1.1b3,
 * section 6).  libmodbus 3.1.6 knows only some of them and cuts the others short. */
#include <stddef.h>
#include <stdint.h>

#include "internal.h"
#include "mbgw.h"

/* Length of a frame whose byte count sits at offset `at`, with `fixed` bytes besides it
 * and the counted data (CRC excluded). */
static int counted(const uint8_t *f, size_t have, size_t at, int fixed)
{
    if (have <= at)
        return 0;
    return fixed + f[at] + CRC_LEN;
}

int mbgw_rtu_reply_length(size_t req_len, const uint8_t *rsp, size_t have)
{
    if (have < 2)
        return 0;
    uint8_t fc = rsp[1];
    if (fc & 0x80)
        return 3 + CRC_LEN; /* address, fc|0x80, exception code */
    switch (fc) {
    case 0x01:
    case 0x02:
    case 0x03:
    case 0x04:
    case 0x0C:
    case 0x11:
    case 0x14:
    case 0x15:
    case 0x17:
        return counted(rsp, have, 2, 3); /* address, fc, byte count, data */
    case 0x05:
    case 0x06:
    case 0x0B:
    case 0x0F:
    case 0x10:
        return 6 + CRC_LEN;
    case 0x07:
        return 3 + CRC_LEN;
    case 0x08:
        return (int)req_len + CRC_LEN; /* diagnostics echo the request's length */
    case 0x16:
        return 8 + CRC_LEN;
    case 0x18: /* 16-bit byte count */
        if (have < 4)
            return 0;
        return 4 + ((rsp[2] << 8) | rsp[3]) + CRC_LEN;
    case 0x2B: {
        if (have < 3)
            return 0;
        if (rsp[2] != 0x0E)
            return MBGW_LEN_UNKNOWN;
        /* Read Device Identification: 8 header bytes, then id, length and value per
         * object */
        if (have < 8)
            return 0;
        size_t pos = 8;
        for (int obj = 0; obj < rsp[7]; obj++) {
            if (have < pos + 2)
                return 0;
            pos += 2 + rsp[pos + 1];
        }
        return (int)pos + CRC_LEN;
    }
    default:
        return MBGW_LEN_UNKNOWN;
    }
}

int mbgw_rtu_request_length(const uint8_t *req, size_t have)
{
    if (have < 2)
        return 0;
    switch (req[1]) {
    case 0x01:
    case 0x02:
    case 0x03:
    case 0x04:
    case 0x05:
    case 0x06:
        return 6 + CRC_LEN;
    case 0x07:
    case 0x0B:
    case 0x0C:
    case 0x11:
        return 2 + CRC_LEN;
    case 0x08: /* sub-function 0 echoes any amount of data */
        if (have < 4)
            return 0;
        return (req[2] == 0 && req[3] == 0) ? MBGW_LEN_UNKNOWN : 6 + CRC_LEN;
    case 0x0F:
    case 0x10:
        return counted(req, have, 6, 7);
    case 0x14:
    case 0x15:
        return counted(req, have, 2, 3);
    case 0x16:
        return 8 + CRC_LEN;
    case 0x17:
        return counted(req, have, 10, 11);
    case 0x18:
        return 4 + CRC_LEN;
    case 0x2B:
        if (have < 3)
            return 0;
        return req[2] == 0x0E ? 5 + CRC_LEN : MBGW_LEN_UNKNOWN;
    default:
        return MBGW_LEN_UNKNOWN;
    }
}
