/* What csrc/table.c (the exchange table's memory) and csrc/table_answer.c (the Modbus
 * server answering from it) share; Python does not see it (the cdef is mbgw.h). */
#ifndef MBGW_TABLE_H
#define MBGW_TABLE_H

#include <pthread.h>
#include <stdint.h>

/* after mbgw.h, which has no include guard (it is also cffi's cdef) */

#define REGISTERS 65536
#define OUTPUTS_FIRST 0x0800 /* outputs, then the free zone: what persistence keeps */
/* the configuration zone: read-only to Modbus and the operator */
#define CONFIG_FIRST 0x8000
#define FUNCTIONS_KNOWN                                                                  \
    (1u << 1 | 1u << 2 | 1u << 3 | 1u << 4 | 1u << 5 | 1u << 6 | 1u << 7 | 1u << 15 |    \
     1u << 16 | 1u << 23)

/* The Modbus limits of a quantity (section 6). */
#define READ_BITS_MAX 2000
#define WRITE_BITS_MAX 1968
#define READ_REGS_MAX 125
#define WRITE_REGS_MAX 123
#define RW_WRITE_REGS_MAX 121

#define ILLEGAL_FUNCTION 0x01
#define ILLEGAL_ADDRESS 0x02
#define ILLEGAL_VALUE 0x03
#define TARGET_FAILED 0x0B /* a stale register: its scenario's device does not answer */

#define COIL_ON 0xFF00

#define OUTCOMES 3 /* MBGW_TABLE_ANSWERED, _EXCEPTION, _BROADCAST */

/* A range whose changes someone waits for: scenarios sent on change, transparent mode's
 * tx area.  The flag is set, and the eventfd written once, by the first change after a
 * take. */
struct watch {
    unsigned first, end; /* end == 0: the slot is free */
    int fd;
    int changed;
    int first_writes; /* a register's first write counts as a change, same value or not */
};

/* The FC 8 counters (sub-functions 11-18, in their order), 16 bits each as FC 8 reads
 * them: a counter wraps. */
enum diag_counter {
    DIAG_BUS_MESSAGES,
    DIAG_BUS_ERRORS,
    DIAG_EXCEPTIONS,
    DIAG_SERVER_MESSAGES,
    DIAG_NO_RESPONSE,
    DIAG_NAKS,
    DIAG_BUSY,
    DIAG_OVERRUNS,
    DIAG_COUNTERS
};

struct mbgw_table {
    uint16_t reg[REGISTERS];
    uint8_t
        watched[REGISTERS / 8]; /* registers inside some watch: the only ones looked up */
    uint8_t
        stale[REGISTERS / 8]; /* registers whose scenario's data is too old to serve */
    uint8_t written[REGISTERS / 8]; /* registers written since start, by anyone */
    unsigned stale_count;           /* 0: no read looks at the bitmap */
    struct watch watches[MBGW_TABLE_WATCHES];
    pthread_mutex_t lock;
    uint32_t functions;
    int line_down;
    int scenario_error;
    const volatile uint8_t *down; /* 256 flags owned by the caller, or NULL */
    uint64_t generation;
    uint64_t by_function[256][OUTCOMES];
    uint64_t by_exception[16];
    uint16_t diag[DIAG_COUNTERS];
    uint8_t ident[MBGW_IDENT_OBJECTS][MBGW_IDENT_OBJECT_MAX]; /* FC 43/14's objects */
    uint8_t ident_len[MBGW_IDENT_OBJECTS];
    uint8_t server_id[MBGW_SERVER_ID_MAX]; /* FC 17's bytes after the byte count */
    uint8_t server_id_len;
};

/* The registers, the table's lock held. */
void put16(uint8_t *p, unsigned v);
void store_registers(mbgw_table *t, unsigned address, unsigned count, const uint8_t *be);
void load_registers(const mbgw_table *t, unsigned address, unsigned count, uint8_t *be);
int get_bit(const mbgw_table *t, unsigned bit);
void set_bit(mbgw_table *t, unsigned bit, int on, int *changed);
int status_byte(const mbgw_table *t);
int any_stale(const mbgw_table *t, unsigned first, unsigned end);

/* The identity functions (csrc/table_ident.c), the lock held. */
int diagnostics(mbgw_table *t, const uint8_t *req, int len, uint8_t *rsp);
int report_server_id(const mbgw_table *t, int len, uint8_t *rsp);
int read_device_id(const mbgw_table *t, const uint8_t *req, int len, uint8_t *rsp);
void count_received(mbgw_table *t);

static inline int beyond(unsigned address, unsigned quantity)
{
    return address + quantity > REGISTERS;
}

static inline int touches_config(unsigned address, unsigned quantity)
{
    return address + quantity > CONFIG_FIRST;
}

#endif
