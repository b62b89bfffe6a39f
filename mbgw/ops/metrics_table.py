"""The exchange table's metric families, from its status dict (mbgw.table.report): its
requests by function and outcome, its exception replies, master mode's serial slave."""
from prometheus_client.core import CounterMetricFamily

_TABLE_SERIAL_ERRORS = {"crc": "crc_errors", "length": "length_errors",
                        "send": "send_failures"}


def table_families(status: dict):
    """The exchange table's families from its status dict (mbgw.table.report)."""
    requests = CounterMetricFamily(
        "mbgw_table_requests", "Requests the exchange table answered, by function code and "
        "outcome (answered; exception: an exception reply; broadcast: done, no reply).",
        labels=["function", "outcome"])
    for function, row in status.get("requests", {}).items():
        for outcome, n in row.items():
            requests.add_metric([str(function), outcome], n)
    yield requests
    exceptions = CounterMetricFamily(
        "mbgw_table_exceptions", "Exception replies the exchange table sent, by code.",
        labels=["code"])
    for code, n in status.get("exceptions", {}).items():
        exceptions.add_metric([code], n)
    yield exceptions
    serial = status.get("serial")
    if serial is not None:
        yield CounterMetricFamily(
            "mbgw_table_serial_requests", "Requests from the serial master for the table's "
            "address (master mode), broadcasts included.", value=serial.get("requests", 0))
        errors = CounterMetricFamily(
            "mbgw_table_serial_errors", "Master mode's serial slave: frames for the table's "
            "address with a bad CRC or LRC (crc) or a bad length (length), and replies that "
            "could not be sent (send).", labels=["kind"])
        for kind, key in _TABLE_SERIAL_ERRORS.items():
            errors.add_metric([kind], serial.get(key, 0))
        yield errors

