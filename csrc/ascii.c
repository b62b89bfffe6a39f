/* Modbus ASCII framing (Modbus over Serial Line V1.02, 2.5.2): ':' then address,
 * function, data and LRC as pairs of hex characters, then CR LF.  libmodbus has no ASCII
 * at all. */
#include <errno.h>
#include <stddef.h>
#include <stdint.h>

#include "mbgw.h"

static const char HEX[] = "0123456789ABCDEF";

uint8_t mbgw_lrc(const uint8_t *buf, size_t len)
{
    uint8_t sum = 0;
    for (size_t i = 0; i < len; i++)
        sum = (uint8_t)(sum + buf[i]);
    return (uint8_t)-sum;
}

int mbgw_ascii_encode(const uint8_t *adu, size_t len, uint8_t *out, size_t cap)
{
    size_t need = 1 + 2 * (len + 1) + 2;
    if (need > cap || need > MBGW_ASCII_MAX_FRAME)
        return -EMSGSIZE;
    size_t pos = 0;
    out[pos++] = ':';
    uint8_t lrc = mbgw_lrc(adu, len);
    for (size_t i = 0; i <= len; i++) {
        uint8_t b = i < len ? adu[i] : lrc;
        out[pos++] = (uint8_t)HEX[b >> 4];
        out[pos++] = (uint8_t)HEX[b & 0x0F];
    }
    out[pos++] = '\r';
    out[pos++] = '\n';
    return (int)pos;
}

static int nibble(uint8_t c)
{
    if (c >= '0' && c <= '9')
        return c - '0';
    if (c >= 'A' && c <= 'F')
        return c - 'A' + 10;
    if (c >= 'a' && c <= 'f') /* accepted on receive, never sent */
        return c - 'a' + 10;
    return -1;
}

int mbgw_ascii_decode(const uint8_t *frame, size_t len, uint8_t *adu, size_t cap)
{
    if (len > MBGW_ASCII_MAX_FRAME)
        return -EMSGSIZE;
    if (len < 1 + 2 * 3 + 2 || frame[0] != ':' || frame[len - 2] != '\r' ||
        frame[len - 1] != '\n')
        return -EBADMSG;
    size_t hex_len = len - 3;
    if (hex_len % 2)
        return -EBADMSG;
    size_t n = hex_len / 2; /* bytes including the LRC */
    if (n - 1 > cap)
        return -EMSGSIZE;
    uint8_t sum = 0;
    for (size_t i = 0; i < n; i++) {
        int hi = nibble(frame[1 + 2 * i]), lo = nibble(frame[2 + 2 * i]);
        if (hi < 0 || lo < 0)
            return -EBADMSG;
        uint8_t b = (uint8_t)(hi << 4 | lo);
        sum = (uint8_t)(sum + b);
        if (i < n - 1)
            adu[i] = b;
    }
    if (sum != 0) /* data + LRC sums to zero */
        return -EILSEQ;
    return (int)(n - 1);
}
