#include <stddef.h>
#include <stdint.h>

#include "mbgw.h"

/* Bitwise form of the Modbus CRC (Serial Line V1.02, section 6.2.2): short and fast
 * enough for frames of at most 256 bytes. */
uint16_t mbgw_crc16(const uint8_t *buf, size_t len)
{
    uint16_t crc = 0xFFFF;
    for (size_t i = 0; i < len; i++) {
        crc ^= buf[i];
        for (int bit = 0; bit < 8; bit++)
            crc = (crc & 1) ? (uint16_t)((crc >> 1) ^ 0xA001) : (uint16_t)(crc >> 1);
    }
    return crc;
}
