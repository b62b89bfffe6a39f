"""The exchange table's figures as plain data, for `mbgw status` (its "table" section, also in
--json) and for /metrics (mbgw.ops.metrics_table reads this dict: ops does not import the
table).

table_status(table, settings, serial, persist) ->
    {"functions": [3, 4, ...],                 the settings in force (TableConfig), when given:
     "direct": true, "units": "247-254",       slave mode's routing
     "address": 17, "port": 502,               master mode's serial address and TCP port
     "requests": {"3": {"answered": n, "exception": n, "broadcast": n}, ...},
                                               by function code (decimal): every function of the
                                               table, and any other code a client asked
     "exceptions": {"0x02": n, ...},           exception replies sent, by code
     "serial": {"requests": n, "crc_errors": n, "length_errors": n, "send_failures": n},
                                               master mode's serial slave (the master line
                                               thread's figures), when given
     "persist": {...},                         the persistence's state as it reports it
                                               ("path", "last_save" (Unix time or null), ...)
     "tcp": {"port": n, "connections": n, "max_connections": n, "connections_accepted": n,
             "connections_refused_limit": n, "connections_bad_header": n,
             "tls_port": n or null, "tls_handshakes": n, "connections_refused_tls": n,
             "connections_tls_probes": n}}
                                               master mode's table TCP server, when given
"""
from mbgw.config.model import TableConfig
from mbgw.config.number_list import number_list_text

SERIAL_KEYS = ("requests", "crc_errors", "length_errors", "send_failures")


def table_status(table, settings: TableConfig | None = None, serial: dict | None = None,
                 persist: dict | None = None, tcp: dict | None = None) -> dict:
    """The "table" section of the status JSON (see the module's docstring)."""
    counts = table.counts()
    status: dict = {}
    if settings is not None:
        status.update(enabled=settings.enabled, functions=list(settings.functions),
                      direct=settings.direct,
                      units=number_list_text(settings.units), address=settings.address,
                      port=settings.port)
    status["requests"] = {str(fc): dict(row)
                          for fc, row in sorted(counts["requests_by_function"].items())}
    status["exceptions"] = {f"0x{code:02x}": n
                            for code, n in sorted(counts["exceptions_by_code"].items())}
    if serial is not None:
        status["serial"] = {key: serial.get(key, 0) for key in SERIAL_KEYS}
    if persist is not None:
        status["persist"] = dict(persist)
    if tcp is not None:
        status["tcp"] = dict(tcp)
    return status
