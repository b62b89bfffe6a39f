/* The exchange table's memory: 65,536 registers that Modbus clients, a serial master and
 * the operator read and write, under one mutex (csrc/table_answer.c answers a Modbus
 * request whole under it, so no reader ever sees half of a write); the operator's and
 * persistence's access, FC 7's flags, stale ranges, the watches of changed values and the
 * counters, plain arrays in the table, so answering allocates nothing. */
#include <errno.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "internal.h"
#include "mbgw.h"
#include "table.h"

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

void put16(uint8_t *p, unsigned v)
{
    p[0] = (uint8_t)(v >> 8);
    p[1] = (uint8_t)v;
}

/* --- the registers, the lock held --- */

static int persisted(unsigned address)
{
    return address >= OUTPUTS_FIRST && address < CONFIG_FIRST;
}

/* first_write: the register's value is the same, but it had never been written. */
static void tell_watchers(mbgw_table *t, unsigned address, int first_write)
{
    for (int i = 0; i < MBGW_TABLE_WATCHES; i++) {
        struct watch *w = &t->watches[i];
        if (address >= w->first && address < w->end && !w->changed &&
            (!first_write || w->first_writes)) {
            w->changed = 1;
            if (w->fd >= 0) {
                uint64_t one = 1;
                /* EAGAIN: already signalled */
                ssize_t n = write(w->fd, &one, sizeof one);
                (void)n;
            }
        }
    }
}

static int bit_of(const uint8_t *map, unsigned address)
{
    return map[address >> 3] >> (address & 7) & 1;
}

/* Every write of a register comes here: Modbus, the operator, scenarios, persistence. */
static void set_register(mbgw_table *t, unsigned address, uint16_t value, int *changed)
{
    int first_write = !bit_of(t->written, address);
    t->written[address >> 3] |= (uint8_t)(1u << (address & 7));
    if (t->reg[address] != value) {
        t->reg[address] = value;
        *changed |= persisted(address);
        if (bit_of(t->watched, address))
            tell_watchers(t, address, 0);
    } else if (first_write && bit_of(t->watched, address)) {
        tell_watchers(t, address, 1);
    }
}

void store_registers(mbgw_table *t, unsigned address, unsigned count, const uint8_t *be)
{
    int changed = 0;
    for (unsigned i = 0; i < count; i++)
        set_register(t, address + i, (uint16_t)be16(be + 2 * i), &changed);
    t->generation += (uint64_t)changed;
}

void load_registers(const mbgw_table *t, unsigned address, unsigned count, uint8_t *be)
{
    for (unsigned i = 0; i < count; i++)
        put16(be + 2 * i, t->reg[address + i]);
}

/* Bit B is bit B % 16 (0 = least significant) of register B / 16. */
int get_bit(const mbgw_table *t, unsigned bit)
{
    return t->reg[bit >> 4] >> (bit & 15) & 1;
}

void set_bit(mbgw_table *t, unsigned bit, int on, int *changed)
{
    uint16_t mask = (uint16_t)(1u << (bit & 15));
    uint16_t old = t->reg[bit >> 4];
    set_register(t, bit >> 4, on ? (uint16_t)(old | mask) : (uint16_t)(old & ~mask),
                 changed);
}

int status_byte(const mbgw_table *t)
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
    return bit_of(t->stale, address);
}

/* Registers [first, end) hold a stale value (a read touching one answers 0x0B). */
int any_stale(const mbgw_table *t, unsigned first, unsigned end)
{
    if (t->stale_count == 0)
        return 0;
    for (unsigned a = first; a < end; a++)
        if (is_stale(t, a))
            return 1;
    return 0;
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
    for (unsigned a = (unsigned)address; a < (unsigned)(address + count); a++)
        t->written[a >> 3] |= (uint8_t)(1u << (a & 7));
    pthread_mutex_unlock(&t->lock);
}

int mbgw_table_unwritten(mbgw_table *t, int first, int count)
{
    if (out_of_range(first, count))
        return -EINVAL;
    int found = -1;
    pthread_mutex_lock(&t->lock);
    for (unsigned a = (unsigned)first; a < (unsigned)(first + count); a++) {
        if (!bit_of(t->written, a)) {
            found = (int)a;
            break;
        }
    }
    pthread_mutex_unlock(&t->lock);
    return found;
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

int mbgw_table_watch(mbgw_table *t, int first, int count, int fd, int first_writes)
{
    if (out_of_range(first, count) || count == 0)
        return -EINVAL;
    pthread_mutex_lock(&t->lock);
    int id = -ENOSPC;
    for (int i = 0; i < MBGW_TABLE_WATCHES; i++) {
        if (t->watches[i].end == 0) {
            t->watches[i] = (struct watch){ (unsigned)first, (unsigned)(first + count),
                                            fd, 0, first_writes };
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
    t->watches[id] = (struct watch){ 0, 0, -1, 0, 0 };
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
