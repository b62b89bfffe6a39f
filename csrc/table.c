/* The exchange table: 65,536 registers that Modbus clients, a serial master and the
 * operator read and write, and the Modbus server that answers a request PDU from it.
 * Modbus Application Protocol V1.1b3, sections 6 (functions) and 7 (exceptions).  Each
 * request runs whole under the table's mutex, so no reader ever sees half of a write; the
 * counters are plain arrays in the table, so answering allocates nothing. */
#include <errno.h>
#include <pthread.h>
#include <unistd.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"
#include "mbgw.h"

#define REGISTERS 65536
#define OUTPUTS_FIRST 0x0800   /* outputs, then the free zone: what persistence keeps */
#define CONFIG_FIRST 0x8000    /* the configuration zone: read-only to Modbus and the operator */
#define FUNCTIONS_KNOWN (1u << 1 | 1u << 2 | 1u << 3 | 1u << 4 | 1u << 5 | 1u << 6 | \
                         1u << 7 | 1u << 15 | 1u << 16 | 1u << 23)

/* The Modbus limits of a quantity (section 6). */
#define READ_BITS_MAX 2000
#define WRITE_BITS_MAX 1968
#define READ_REGS_MAX 125
#define WRITE_REGS_MAX 123
#define RW_WRITE_REGS_MAX 121

#define ILLEGAL_FUNCTION 0x01
#define ILLEGAL_ADDRESS 0x02
#define ILLEGAL_VALUE 0x03
#define TARGET_FAILED 0x0B    /* a stale register: its scenario's device does not answer */

#define COIL_ON 0xFF00

#define OUTCOMES 3 /* MBGW_TABLE_ANSWERED, _EXCEPTION, _BROADCAST */

/* A range whose changes someone waits for: scenarios sent on change, transparent mode's tx
 * area.  The flag is set, and the eventfd written once, by the first change after a take. */
struct watch {
    unsigned first, end;        /* end == 0: the slot is free */
    int fd;
    int changed;
};

struct mbgw_table {
    uint16_t reg[REGISTERS];
    uint8_t watched[REGISTERS / 8];   /* registers inside some watch: the only ones looked up */
    uint8_t stale[REGISTERS / 8];     /* registers whose scenario's data is too old to serve */
    unsigned stale_count;             /* 0: no read looks at the bitmap */
    struct watch watches[MBGW_TABLE_WATCHES];
    pthread_mutex_t lock;
    uint32_t functions;
    int line_down;
    int scenario_error;
    const volatile uint8_t *down;   /* 256 flags owned by the caller, or NULL */
    uint64_t generation;
    uint64_t by_function[256][OUTCOMES];
    uint64_t by_exception[16];
};

mbgw_table *mbgw_table_new(void)
{
    mbgw_table *t = calloc(1, sizeof *t);
    if (!t)
        return NULL;
    pthread_mutex_init(&t->lock, NULL);
    t->functions = FUNCTIONS_KNOWN;
    return t;
}

void mbgw_table_free(mbgw_table *t)
{
    if (!t)
        return;
    pthread_mutex_destroy(&t->lock);
    free(t);
}

void mbgw_table_set_functions(mbgw_table *t, uint32_t mask)
{
    pthread_mutex_lock(&t->lock);
    t->functions = mask & FUNCTIONS_KNOWN;
    pthread_mutex_unlock(&t->lock);
}

static unsigned be16(const uint8_t *p)
{
    return (unsigned)p[0] << 8 | p[1];
}

static void put16(uint8_t *p, unsigned v)
{
    p[0] = (uint8_t)(v >> 8);
    p[1] = (uint8_t)v;
}

/* --- the registers, the lock held --- */

static int persisted(unsigned address)
{
    return address >= OUTPUTS_FIRST && address < CONFIG_FIRST;
}

static void tell_watchers(mbgw_table *t, unsigned address)
{
    for (int i = 0; i < MBGW_TABLE_WATCHES; i++) {
        struct watch *w = &t->watches[i];
        if (address >= w->first && address < w->end && !w->changed) {
            w->changed = 1;
            if (w->fd >= 0) {
                uint64_t one = 1;
                ssize_t n = write(w->fd, &one, sizeof one);  /* EAGAIN: already signalled */
                (void)n;
            }
        }
    }
}

static void set_register(mbgw_table *t, unsigned address, uint16_t value, int *changed)
{
    if (t->reg[address] != value) {
        t->reg[address] = value;
        *changed |= persisted(address);
        if (t->watched[address >> 3] >> (address & 7) & 1)
            tell_watchers(t, address);
    }
}

static void store_registers(mbgw_table *t, unsigned address, unsigned count,
                            const uint8_t *be)
{
    int changed = 0;
    for (unsigned i = 0; i < count; i++)
        set_register(t, address + i, (uint16_t)be16(be + 2 * i), &changed);
    t->generation += (uint64_t)changed;
}

static void load_registers(const mbgw_table *t, unsigned address, unsigned count, uint8_t *be)
{
    for (unsigned i = 0; i < count; i++)
        put16(be + 2 * i, t->reg[address + i]);
}

/* Bit B is bit B % 16 (0 = least significant) of register B / 16. */
static int get_bit(const mbgw_table *t, unsigned bit)
{
    return t->reg[bit >> 4] >> (bit & 15) & 1;
}

static void set_bit(mbgw_table *t, unsigned bit, int on, int *changed)
{
    uint16_t mask = (uint16_t)(1u << (bit & 15));
    uint16_t old = t->reg[bit >> 4];
    set_register(t, bit >> 4, on ? (uint16_t)(old | mask) : (uint16_t)(old & ~mask), changed);
}

static int status_byte(const mbgw_table *t)
{
    int status = (t->line_down ? 1 : 0) | (t->scenario_error ? 2 : 0);
    if (t->down)
        for (int address = 0; address < 256; address++)
            if (t->down[address])
                return status | 4;
    return status;
}

static int is_stale(const mbgw_table *t, unsigned address)
{
    return t->stale[address >> 3] >> (address & 7) & 1;
}

/* Registers [first, end) hold a stale value (a read touching one answers 0x0B). */
static int any_stale(const mbgw_table *t, unsigned first, unsigned end)
{
    if (t->stale_count == 0)
        return 0;
    for (unsigned a = first; a < end; a++)
        if (is_stale(t, a))
            return 1;
    return 0;
}

/* --- the functions: each checks the request, then answers it into rsp; a positive result
 * is the reply's length, a negative one an exception code --- */

static int beyond(unsigned address, unsigned quantity)
{
    return address + quantity > REGISTERS;
}

static int touches_config(unsigned address, unsigned quantity)
{
    return address + quantity > CONFIG_FIRST;
}

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
    unsigned write_address = be16(req + 5), write_quantity = be16(req + 7), bytes = req[9];
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
    if (fc >= 32 || !(t->functions >> fc & 1))
        return -ILLEGAL_FUNCTION;
    rsp[0] = fc;
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

int mbgw_table_answer(mbgw_table *t, const uint8_t *req, int len, uint8_t *rsp, int broadcast)
{
    if (len < 1)
        return 0;
    uint8_t fc = req[0];
    /* A broadcast's reply is built in a scratch buffer and dropped: reads are ignored. */
    uint8_t scratch[MBGW_PDU_MAX];
    pthread_mutex_lock(&t->lock);
    if (broadcast) {
        if (writes(fc))
            serve(t, req, len, scratch);
        t->by_function[fc][MBGW_TABLE_BROADCAST]++;
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
    } else {
        t->by_function[fc][MBGW_TABLE_ANSWERED]++;
    }
    pthread_mutex_unlock(&t->lock);
    return n;
}

int mbgw_table_answer_mbap(mbgw_table *t, const uint8_t *adu, int len, uint8_t *rsp,
                           int broadcast)
{
    if (len < MBAP_LEN + 1 || be16(adu + 2) != 0 || (int)be16(adu + 4) != len - MBAP_HEAD_LEN)
        return -EBADMSG;
    int n = mbgw_table_answer(t, adu + MBAP_LEN, len - MBAP_LEN, rsp + MBAP_LEN, broadcast);
    if (n == 0)
        return 0;
    memcpy(rsp, adu, 2);  /* the transaction id */
    put16(rsp + 2, 0);
    put16(rsp + 4, (unsigned)n + 1);
    rsp[6] = adu[6];      /* the unit id */
    return MBAP_LEN + n;
}

/* --- the operator's and persistence's access --- */

static int out_of_range(int address, int count)
{
    return address < 0 || count < 0 || address + count > REGISTERS;
}

int mbgw_table_read(mbgw_table *t, int address, int count, uint16_t *out)
{
    if (out_of_range(address, count))
        return -EINVAL;
    pthread_mutex_lock(&t->lock);
    memcpy(out, t->reg + address, (size_t)count * sizeof *out);
    pthread_mutex_unlock(&t->lock);
    return 0;
}

int mbgw_table_write(mbgw_table *t, int address, int count, const uint16_t *in)
{
    if (out_of_range(address, count))
        return -EINVAL;
    if (touches_config((unsigned)address, (unsigned)count))
        return -EPERM;
    int changed = 0;
    pthread_mutex_lock(&t->lock);
    for (int i = 0; i < count; i++)
        set_register(t, (unsigned)(address + i), in[i], &changed);
    t->generation += (uint64_t)changed;
    pthread_mutex_unlock(&t->lock);
    return 0;
}

void mbgw_table_set_config(mbgw_table *t, int address, int count, const uint16_t *in)
{
    if (out_of_range(address, count) || address < CONFIG_FIRST)
        return;
    pthread_mutex_lock(&t->lock);
    memcpy(t->reg + address, in, (size_t)count * sizeof *in);
    pthread_mutex_unlock(&t->lock);
}

void mbgw_table_set_flags(mbgw_table *t, int line_down, int scenario_error)
{
    pthread_mutex_lock(&t->lock);
    t->line_down = line_down;
    t->scenario_error = scenario_error;
    pthread_mutex_unlock(&t->lock);
}

void mbgw_table_set_flag(mbgw_table *t, int flag, int on)
{
    pthread_mutex_lock(&t->lock);
    if (flag == MBGW_TABLE_LINE_DOWN)
        t->line_down = on;
    else if (flag == MBGW_TABLE_SCENARIO_ERROR)
        t->scenario_error = on;
    pthread_mutex_unlock(&t->lock);
}

void mbgw_table_watch_down(mbgw_table *t, const uint8_t *down)
{
    pthread_mutex_lock(&t->lock);
    t->down = down;
    pthread_mutex_unlock(&t->lock);
}

int mbgw_table_write_bits(mbgw_table *t, int bit, int count, const uint8_t *packed)
{
    if (bit < 0 || count < 0 || bit + count > REGISTERS)
        return -EINVAL;
    int changed = 0;
    pthread_mutex_lock(&t->lock);
    for (int i = 0; i < count; i++)
        set_bit(t, (unsigned)(bit + i), packed[i / 8] >> (i % 8) & 1, &changed);
    t->generation += (uint64_t)changed;
    pthread_mutex_unlock(&t->lock);
    return 0;
}

int mbgw_table_set_stale(mbgw_table *t, int first, int count, int on)
{
    if (out_of_range(first, count))
        return -EINVAL;
    pthread_mutex_lock(&t->lock);
    for (unsigned a = (unsigned)first; a < (unsigned)(first + count); a++) {
        if (is_stale(t, a) == !!on)
            continue;
        t->stale[a >> 3] ^= (uint8_t)(1u << (a & 7));
        t->stale_count += on ? 1u : (unsigned)-1;
    }
    pthread_mutex_unlock(&t->lock);
    return 0;
}

uint64_t mbgw_table_persist_generation(mbgw_table *t)
{
    pthread_mutex_lock(&t->lock);
    uint64_t generation = t->generation;
    pthread_mutex_unlock(&t->lock);
    return generation;
}

void mbgw_table_counts(mbgw_table *t, uint64_t *by_function, uint64_t *by_exception)
{
    pthread_mutex_lock(&t->lock);
    memcpy(by_function, t->by_function, sizeof t->by_function);
    memcpy(by_exception, t->by_exception, sizeof t->by_exception);
    pthread_mutex_unlock(&t->lock);
}

void mbgw_table_reset_counts(mbgw_table *t)
{
    pthread_mutex_lock(&t->lock);
    memset(t->by_function, 0, sizeof t->by_function);
    memset(t->by_exception, 0, sizeof t->by_exception);
    pthread_mutex_unlock(&t->lock);
}

/* --- watches --- */

static void mark_watched(mbgw_table *t)
{
    memset(t->watched, 0, sizeof t->watched);
    for (int i = 0; i < MBGW_TABLE_WATCHES; i++)
        for (unsigned a = t->watches[i].first; a < t->watches[i].end; a++)
            t->watched[a >> 3] |= (uint8_t)(1u << (a & 7));
}

int mbgw_table_watch(mbgw_table *t, int first, int count, int fd)
{
    if (out_of_range(first, count) || count == 0)
        return -EINVAL;
    pthread_mutex_lock(&t->lock);
    int id = -ENOSPC;
    for (int i = 0; i < MBGW_TABLE_WATCHES; i++) {
        if (t->watches[i].end == 0) {
            t->watches[i] = (struct watch){(unsigned)first, (unsigned)(first + count), fd, 0};
            id = i;
            break;
        }
    }
    if (id >= 0)
        mark_watched(t);
    pthread_mutex_unlock(&t->lock);
    return id;
}

void mbgw_table_unwatch(mbgw_table *t, int id)
{
    if (id < 0 || id >= MBGW_TABLE_WATCHES)
        return;
    pthread_mutex_lock(&t->lock);
    t->watches[id] = (struct watch){0, 0, -1, 0};
    mark_watched(t);
    pthread_mutex_unlock(&t->lock);
}

int mbgw_table_take_change(mbgw_table *t, int id, uint16_t *out)
{
    if (id < 0 || id >= MBGW_TABLE_WATCHES)
        return -EINVAL;
    pthread_mutex_lock(&t->lock);
    struct watch *w = &t->watches[id];
    int changed = w->changed;
    w->changed = 0;
    if (out && w->end)
        memcpy(out, t->reg + w->first, (w->end - w->first) * sizeof *out);
    pthread_mutex_unlock(&t->lock);
    return changed;
}
