/* The raw line monitor (mbgw trace --raw): while a capture is set, every byte read from
 * or written to the serial line is appended to it as records, each
 *   direction (MBGW_CAPTURE_RX or _TX), time (int64 CLOCK_MONOTONIC ns, native order),
 *   length (uint16, native order), the bytes;
 * the line's thread (the only one that reads or writes the line) drains it between
 * transactions.  With none set, a read costs one pointer test.  Each line thread has its
 * own: with many lines, one line's bytes never land in another's capture. */
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <modbus.h>

#include "internal.h"
#include "mbgw.h"

static _Thread_local struct mbgw_capture *capture;

void mbgw_capture_set(struct mbgw_capture *c)
{
    capture = c;
}

void mbgw_capture_unset(struct mbgw_capture *c)
{
    if (capture == c)
        capture = NULL;
}

void capture_note(int direction, const uint8_t *bytes, size_t len)
{
    struct mbgw_capture *c = capture;
    if (c == NULL || len == 0)
        return;
    if (len > 0xffff || c->len + MBGW_CAPTURE_HEAD + len > c->cap) {
        c->dropped += len; /* nobody drained it in time */
        return;
    }
    int64_t t = now_ns();
    uint16_t n = (uint16_t)len;
    uint8_t *at = c->buf + c->len;
    at[0] = (uint8_t)direction;
    memcpy(at + 1, &t, sizeof t);
    memcpy(at + 1 + sizeof t, &n, sizeof n);
    memcpy(at + MBGW_CAPTURE_HEAD, bytes, len);
    c->len += MBGW_CAPTURE_HEAD + len;
}

int mbgw_send_rtu(struct _modbus *ctx, const uint8_t *adu, size_t len)
{
    if (modbus_send_raw_request(ctx, adu, (int)len) < 0)
        return -1;
    if (capture != NULL && len + CRC_LEN <= MBGW_RTU_MAX_ADU) {
        uint8_t frame[MBGW_RTU_MAX_ADU];
        uint16_t crc = mbgw_crc16(adu, len);
        memcpy(frame, adu, len);
        frame[len] = crc & 0xff;
        frame[len + 1] = crc >> 8;
        capture_note(MBGW_CAPTURE_TX, frame, len + CRC_LEN);
    }
    return 0;
}
