/* The Modbus server of the exchange table: a request PDU (or MBAP frame) answered from
 * its registers, under the table's lock.  Modbus Application Protocol V1.1b3, sections 6
 * (functions) and 7 (exceptions); the memory itself is csrc/table.c. */
#include <errno.h>
#include <pthread.h>
#include <stdint.h>
#include <string.h>

#include "internal.h"
#include "mbgw.h"
#include "table.h"

/* --- the functions: each checks the request, then answers it into rsp; a positive result
 * is the reply's length, a negative one an exception code --- */

static int read_bits(mbgw_table *t, const uint8_t *req, int len, uint8_t *rsp)
{
    if (len != 5)
        return -ILLEGAL_VALUE;
    unsigned address = be16(req + 1), quantity = be16(req + 3);
    if (quantity < 1 || quantity > READ_BITS_MAX)
        return -ILLEGAL_VALUE;
    if (beyond(address, quantity))
        return -ILLEGAL_ADDRESS;
    if (any_stale(t, address >> 4, ((address + quantity - 1) >> 4) + 1))
        return -TARGET_FAILED;
    unsigned bytes = (quantity + 7) / 8;
    rsp[1] = (uint8_t)bytes;
    memset(rsp + 2, 0, bytes);
    for (unsigned i = 0; i < quantity; i++)
        rsp[2 + i / 8] |= (uint8_t)(get_bit(t, address + i) << (i % 8));
    return 2 + (int)bytes;
}

static int read_registers(mbgw_table *t, const uint8_t *req, int len, uint8_t *rsp)
{
    if (len != 5)
        return -ILLEGAL_VALUE;
    unsigned address = be16(req + 1), quantity = be16(req + 3);
    if (quantity < 1 || quantity > READ_REGS_MAX)
        return -ILLEGAL_VALUE;
    if (beyond(address, quantity))
        return -ILLEGAL_ADDRESS;
    if (any_stale(t, address, address + quantity))
        return -TARGET_FAILED;
    rsp[1] = (uint8_t)(2 * quantity);
    load_registers(t, address, quantity, rsp + 2);
    return 2 + 2 * (int)quantity;
}

static int echo(const uint8_t *req, uint8_t *rsp)
{
    memcpy(rsp + 1, req + 1, 4);
    return 5;
}

static int write_bit(mbgw_table *t, const uint8_t *req, int len, uint8_t *rsp)
{
    if (len != 5)
        return -ILLEGAL_VALUE;
    unsigned value = be16(req + 3);
    if (value != 0 && value != COIL_ON)
        return -ILLEGAL_VALUE;
    int changed = 0;
    set_bit(t, be16(req + 1), value == COIL_ON, &changed);
    t->generation += (uint64_t)changed;
    return echo(req, rsp);
}

static int write_register(mbgw_table *t, const uint8_t *req, int len, uint8_t *rsp)
{
    if (len != 5)
        return -ILLEGAL_VALUE;
    unsigned address = be16(req + 1);
    if (touches_config(address, 1))
        return -ILLEGAL_ADDRESS;
    store_registers(t, address, 1, req + 3);
    return echo(req, rsp);
}

static int write_bits(mbgw_table *t, const uint8_t *req, int len, uint8_t *rsp)
{
    if (len < 6)
        return -ILLEGAL_VALUE;
    unsigned address = be16(req + 1), quantity = be16(req + 3), bytes = req[5];
    if (quantity < 1 || quantity > WRITE_BITS_MAX || bytes != (quantity + 7) / 8 ||
        (unsigned)len != 6 + bytes)
        return -ILLEGAL_VALUE;
    if (beyond(address, quantity))
        return -ILLEGAL_ADDRESS;
    int changed = 0;
    for (unsigned i = 0; i < quantity; i++)
        set_bit(t, address + i, req[6 + i / 8] >> (i % 8) & 1, &changed);
    t->generation += (uint64_t)changed;
    return echo(req, rsp);
}

static int write_registers(mbgw_table *t, const uint8_t *req, int len, uint8_t *rsp)
{
    if (len < 6)
        return -ILLEGAL_VALUE;
    unsigned address = be16(req + 1), quantity = be16(req + 3), bytes = req[5];
    if (quantity < 1 || quantity > WRITE_REGS_MAX || bytes != 2 * quantity ||
        (unsigned)len != 6 + bytes)
        return -ILLEGAL_VALUE;
    if (beyond(address, quantity) || touches_config(address, quantity))
        return -ILLEGAL_ADDRESS;
    store_registers(t, address, quantity, req + 6);
    return echo(req, rsp);
}

/* FC 23: the write first, then the read (section 6.17), under the one lock. */
static int read_write_registers(mbgw_table *t, const uint8_t *req, int len, uint8_t *rsp)
{
    if (len < 10)
        return -ILLEGAL_VALUE;
    unsigned read_address = be16(req + 1), read_quantity = be16(req + 3);
    unsigned write_address = be16(req + 5), write_quantity = be16(req + 7),
             bytes = req[9];
    if (read_quantity < 1 || read_quantity > READ_REGS_MAX || write_quantity < 1 ||
        write_quantity > RW_WRITE_REGS_MAX || bytes != 2 * write_quantity ||
        (unsigned)len != 10 + bytes)
        return -ILLEGAL_VALUE;
    if (beyond(read_address, read_quantity) || beyond(write_address, write_quantity) ||
        touches_config(write_address, write_quantity))
        return -ILLEGAL_ADDRESS;
    if (any_stale(t, read_address, read_address + read_quantity))
        return -TARGET_FAILED;
    store_registers(t, write_address, write_quantity, req + 10);
    rsp[1] = (uint8_t)(2 * read_quantity);
    load_registers(t, read_address, read_quantity, rsp + 2);
    return 2 + 2 * (int)read_quantity;
}

static int exception_status(mbgw_table *t, int len, uint8_t *rsp)
{
    if (len != 1)
        return -ILLEGAL_VALUE;
    rsp[1] = (uint8_t)status_byte(t);
    return 2;
}

static int serve(mbgw_table *t, const uint8_t *req, int len, uint8_t *rsp)
{
    uint8_t fc = req[0];
    rsp[0] = fc;
    switch (fc) {
    case 0x08:
        return diagnostics(t, req, len, rsp);
    case 0x11:
        return report_server_id(t, len, rsp);
    case 0x2B:
        return read_device_id(t, req, len, rsp);
    }
    if (fc >= 32 || !(t->functions >> fc & 1))
        return -ILLEGAL_FUNCTION;
    switch (fc) {
    case 0x01:
    case 0x02:
        return read_bits(t, req, len, rsp);
    case 0x03:
    case 0x04:
        return read_registers(t, req, len, rsp);
    case 0x05:
        return write_bit(t, req, len, rsp);
    case 0x06:
        return write_register(t, req, len, rsp);
    case 0x07:
        return exception_status(t, len, rsp);
    case 0x0F:
        return write_bits(t, req, len, rsp);
    case 0x10:
        return write_registers(t, req, len, rsp);
    default: /* 0x17, the last one FUNCTIONS_KNOWN holds */
        return read_write_registers(t, req, len, rsp);
    }
}

static int writes(uint8_t fc)
{
    return fc == 0x05 || fc == 0x06 || fc == 0x0F || fc == 0x10 || fc == 0x17;
}

int mbgw_table_answer(mbgw_table *t, const uint8_t *req, int len, uint8_t *rsp,
                      int broadcast)
{
    if (len < 1) {
        mbgw_table_count_bad_frame(t);
        return 0;
    }
    uint8_t fc = req[0];
    /* A broadcast's reply is built in a scratch buffer and dropped: reads are ignored. */
    uint8_t scratch[MBGW_PDU_MAX];
    pthread_mutex_lock(&t->lock);
    count_received(t);
    if (broadcast) {
        if (writes(fc))
            serve(t, req, len, scratch);
        t->by_function[fc][MBGW_TABLE_BROADCAST]++;
        t->diag[DIAG_NO_RESPONSE]++;
        pthread_mutex_unlock(&t->lock);
        return 0;
    }
    int n = serve(t, req, len, rsp);
    if (n < 0) {
        rsp[0] = (uint8_t)(fc | 0x80);
        rsp[1] = (uint8_t)-n;
        n = 2;
        t->by_function[fc][MBGW_TABLE_EXCEPTION]++;
        t->by_exception[rsp[1]]++;
        t->diag[DIAG_EXCEPTIONS]++;
    } else {
        t->by_function[fc][MBGW_TABLE_ANSWERED]++;
    }
    pthread_mutex_unlock(&t->lock);
    return n;
}

int mbgw_table_answer_mbap(mbgw_table *t, const uint8_t *adu, int len, uint8_t *rsp,
                           int broadcast)
{
    if (len < MBAP_LEN || mbgw_mbap_frame_len(be16(adu + 2), be16(adu + 4)) != len) {
        mbgw_table_count_bad_frame(t);
        return -EBADMSG;
    }
    int n =
        mbgw_table_answer(t, adu + MBAP_LEN, len - MBAP_LEN, rsp + MBAP_LEN, broadcast);
    if (n == 0)
        return 0;
    memcpy(rsp, adu, 2); /* the transaction id */
    put16(rsp + 2, 0);
    put16(rsp + 4, (unsigned)n + 1);
    rsp[6] = adu[6]; /* the unit id */
    return MBAP_LEN + n;
}
