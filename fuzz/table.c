/* csrc/table_answer.c: the exchange table's answers to any request, as a PDU and as a
 * Modbus TCP frame.  Input: flags (bit 0 broadcast, bit 1 the MBAP form, bit 2 make the
 * registers the request touches first stale, bit 3 only some functions enabled: the next
 * byte's bits), then the request.
 * The identity functions (csrc/table_ident.c) answer from long strings set once.
 * Rules: a PDU answer is 0 (broadcast, nothing to send) or 2..253 bytes: the request's
 * function code, or its exception (0x01, 0x02, 0x03 or 0x0B) in 2 bytes; an MBAP answer
 * is -EBADMSG for a bad header, 0, or the reply with the request's transaction and unit
 * id, protocol id 0 and a length field that is its own; nothing is read or written past
 * the buffers (AddressSanitizer). */
#include <errno.h>
#include <string.h>

#include "internal.h"
#include "mbgw.h"

#include "harness.h"

static mbgw_table *table;

static void check_pdu(const uint8_t *req, int n, const uint8_t *rsp, int broadcast)
{
    MUST(n >= 0 && n <= MBGW_PDU_MAX);
    if (broadcast || n == 0) {
        MUST(n == 0);
        return;
    }
    if (rsp[0] == req[0] && !(req[0] & 0x80))
        return; /* a reply */
    MUST(n == 2 && rsp[0] == (req[0] | 0x80));
    MUST(rsp[1] == 0x01 || rsp[1] == 0x02 || rsp[1] == 0x03 || rsp[1] == 0x0B);
}

static void one(const uint8_t *data, size_t len)
{
    if (table == NULL) {
        table = mbgw_table_new();
        MUST(table != NULL);
        /* identity objects long enough that FC 43/14's streams need More Follows */
        static const uint8_t text[MBGW_SERVER_ID_MAX] = { 'm', 'b', 'g', 'w' };
        for (int id = 0; id < MBGW_IDENT_OBJECTS; id++)
            MUST(mbgw_table_set_identity(table, id, text, 40 * id) == 0);
        MUST(mbgw_table_set_server_id(table, text, MBGW_SERVER_ID_MAX) == 0);
    }
    if (len < 2)
        return;
    uint8_t flags = data[0];
    int broadcast = flags & 1;
    size_t at = 1;
    mbgw_table_set_functions(table, 0xFFFFFFFFu);
    if (flags & 8) {
        uint32_t mask = (uint32_t)data[at++] << 1; /* functions 1..8 */
        mbgw_table_set_functions(table, mask | (1u << 15) | (1u << 16) | (1u << 23));
    }
    if (len <= at)
        return;
    const uint8_t *req = data + at;
    size_t req_len = len - at;
    int first = -1;
    if ((flags & 4) && req_len >= (flags & 2 ? 10u : 3u)) {
        const uint8_t *pdu = flags & 2 ? req + MBAP_LEN : req;
        first = (pdu[1] << 8 | pdu[2]) & 0xFFFF;
        MUST(mbgw_table_set_stale(table, first, 1, 1) == 0);
    }
    uint8_t *copy = exact_copy(req, req_len);
    if (flags & 2) {
        uint8_t *rsp = malloc(MBGW_MBAP_MAX);
        MUST(rsp != NULL);
        int n = mbgw_table_answer_mbap(table, copy, (int)req_len, rsp, broadcast);
        MUST(n == -EBADMSG || n == 0 || (n > MBAP_LEN && n <= MBGW_MBAP_MAX));
        if (n > 0) {
            MUST(memcmp(rsp, copy, 2) == 0 && rsp[2] == 0 && rsp[3] == 0);
            MUST((rsp[4] << 8 | rsp[5]) == n - MBAP_HEAD_LEN && rsp[6] == copy[6]);
            check_pdu(copy + MBAP_LEN, n - MBAP_LEN, rsp + MBAP_LEN, broadcast);
        }
        free(rsp);
    } else {
        uint8_t *rsp = malloc(MBGW_PDU_MAX);
        MUST(rsp != NULL);
        int n = mbgw_table_answer(table, copy, (int)req_len, rsp, broadcast);
        check_pdu(copy, n, rsp, broadcast);
        free(rsp);
    }
    free(copy);
    if (first >= 0)
        MUST(mbgw_table_set_stale(table, first, 1, 0) == 0);
}
