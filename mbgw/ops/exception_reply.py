"""The one rule, for both modes, of the gateway's own answer to a request that no device
answered: with --exception, exception 0x0A (gateway path unavailable: the line, the route or
the server cannot be reached) or 0x0B (gateway target failed to respond), counted line-wide and
against the device; without it, silence.  A broadcast gets no answer at all, so callers never
ask for one."""
from mbgw.protocol import pdu


def gateway_exception(enabled: bool, function: int, code: int, counters,
                      device=None) -> bytes | None:
    """The exception PDU for the request's function, or None (silence) when not enabled.
    device: the serial address's statistics (mbgw.ops.device_stats), when there is one."""
    if not enabled:
        return None
    counters.gateway_exceptions += 1
    if device is not None:
        device.gateway_exception(code)
    return pdu.exception_pdu(function, code)
