/* The table's identity functions, answered on every unit that reaches the table (and on
 * the gateway unit): FC 8 Diagnostics (sub-functions 0 and 10-18), FC 17 Report Server
 * ID and FC 43/14 Read Device Identification.  Modbus Application Protocol V1.1b3,
 * sections 6.8, 6.13 and 6.21; the counters are those of the Modbus over serial line
 * specification V1.02, section 6.1.  The strings are set once per configuration
 * (mbgw_table_set_identity, mbgw_table_set_server_id), so answering allocates nothing. */
#include <errno.h>
#include <pthread.h>
#include <stdint.h>
#include <string.h>

#include "internal.h"
#include "mbgw.h"
#include "table.h"

#define MEI_DEVICE_ID 0x0E
/* basic, regular and extended identification, stream and individual access (6.21) */
#define CONFORMITY 0x83
#define READ_BASIC 0x01
#define READ_REGULAR 0x02
#define READ_EXTENDED 0x03
#define READ_ONE 0x04
#define DEVICE_ID_HEAD                                                                   \
    7 /* FC, MEI type, code, conformity, more follows, next id, count */
#define RUN_INDICATOR_ON 0xFF

#define DIAG_RETURN_QUERY 0x00
#define DIAG_CLEAR_COUNTERS 0x0A
#define DIAG_FIRST_COUNTER 0x0B /* bus message count; the others follow in order */
#define DIAG_LAST_COUNTER 0x12  /* bus character overrun count */

void count_received(mbgw_table *t)
{
    t->diag[DIAG_BUS_MESSAGES]++;
    t->diag[DIAG_SERVER_MESSAGES]++;
}

void mbgw_table_count_bad_frame(mbgw_table *t)
{
    pthread_mutex_lock(&t->lock);
    t->diag[DIAG_BUS_MESSAGES]++;
    t->diag[DIAG_BUS_ERRORS]++;
    pthread_mutex_unlock(&t->lock);
}

/* --- FC 8 --- */

int diagnostics(mbgw_table *t, const uint8_t *req, int len, uint8_t *rsp)
{
    if (len < 3 || len > MBGW_PDU_MAX)
        return -ILLEGAL_VALUE;
    unsigned sub = be16(req + 1);
    if (sub == DIAG_RETURN_QUERY) {
        memcpy(rsp, req, (size_t)len); /* the whole request, looped back */
        return len;
    }
    if (sub != DIAG_CLEAR_COUNTERS &&
        (sub < DIAG_FIRST_COUNTER || sub > DIAG_LAST_COUNTER))
        return -ILLEGAL_FUNCTION; /* a sub-function the table does not support */
    if (len != 5 || be16(req + 3) != 0)
        return -ILLEGAL_VALUE;
    memcpy(rsp, req, 3);
    if (sub == DIAG_CLEAR_COUNTERS) {
        memset(t->diag, 0, sizeof t->diag);
        put16(rsp + 3, 0);
    } else {
        put16(rsp + 3, t->diag[sub - DIAG_FIRST_COUNTER]);
    }
    return 5;
}

/* --- FC 17 --- */

int report_server_id(const mbgw_table *t, int len, uint8_t *rsp)
{
    if (len != 1)
        return -ILLEGAL_VALUE;
    rsp[1] = t->server_id_len;
    memcpy(rsp + 2, t->server_id, t->server_id_len);
    return 2 + t->server_id_len;
}

/* --- FC 43/14 --- */

/* The last object of a stream's category: basic 0-2, regular and extended 0-6 (no
 * extended objects). */
static unsigned last_object(unsigned code)
{
    return code == READ_BASIC ? 2 : MBGW_IDENT_OBJECTS - 1;
}

static int put_object(const mbgw_table *t, unsigned id, uint8_t *at)
{
    at[0] = (uint8_t)id;
    at[1] = t->ident_len[id];
    memcpy(at + 2, t->ident[id], t->ident_len[id]);
    return 2 + t->ident_len[id];
}

int read_device_id(const mbgw_table *t, const uint8_t *req, int len, uint8_t *rsp)
{
    if (len >= 2 && req[1] != MEI_DEVICE_ID)
        return -ILLEGAL_FUNCTION; /* an encapsulated interface the table does not have */
    if (len != 4)
        return -ILLEGAL_VALUE;
    unsigned code = req[2], id = req[3];
    if (code < READ_BASIC || code > READ_ONE)
        return -ILLEGAL_VALUE;
    memcpy(rsp, req, 3);
    rsp[3] = CONFORMITY;
    rsp[4] = 0; /* more follows */
    rsp[5] = 0; /* next object id */
    int n = DEVICE_ID_HEAD;
    if (code == READ_ONE) {
        if (id >= MBGW_IDENT_OBJECTS)
            return -ILLEGAL_ADDRESS;
        rsp[6] = 1;
        return n + put_object(t, id, rsp + n);
    }
    /* a stream begins at the object asked for, or at 0 when it is not in the category */
    if (id > last_object(code))
        id = 0;
    unsigned count = 0;
    for (; id <= last_object(code); id++) {
        if (n + 2 + t->ident_len[id] > MBGW_PDU_MAX) {
            rsp[4] = 0xFF;
            rsp[5] = (uint8_t)id;
            break;
        }
        n += put_object(t, id, rsp + n);
        count++;
    }
    rsp[6] = (uint8_t)count;
    return n;
}

/* --- setting them --- */

int mbgw_table_set_identity(mbgw_table *t, int object, const uint8_t *value, int len)
{
    if (object < 0 || object >= MBGW_IDENT_OBJECTS || len < 0 ||
        len > MBGW_IDENT_OBJECT_MAX)
        return -EINVAL;
    pthread_mutex_lock(&t->lock);
    memcpy(t->ident[object], value, (size_t)len);
    t->ident_len[object] = (uint8_t)len;
    pthread_mutex_unlock(&t->lock);
    return 0;
}

int mbgw_table_set_server_id(mbgw_table *t, const uint8_t *data, int len)
{
    if (len < 0 || len > MBGW_SERVER_ID_MAX)
        return -EINVAL;
    pthread_mutex_lock(&t->lock);
    memcpy(t->server_id, data, (size_t)len);
    t->server_id_len = (uint8_t)len;
    pthread_mutex_unlock(&t->lock);
    return 0;
}

void mbgw_table_count_refused(mbgw_table *t, int broadcast)
{
    pthread_mutex_lock(&t->lock);
    count_received(t);
    t->diag[broadcast ? DIAG_NO_RESPONSE : DIAG_EXCEPTIONS]++;
    pthread_mutex_unlock(&t->lock);
}

void mbgw_table_diagnostics(mbgw_table *t, uint16_t *out)
{
    pthread_mutex_lock(&t->lock);
    memcpy(out, t->diag, sizeof t->diag);
    pthread_mutex_unlock(&t->lock);
}
