"""The operator's access to the exchange table through the control socket: the commands
"table-read" ({"address", "count", "bits"}) and "table-write" ({"address", "values"}) that
`mbgw table read` and `mbgw table write` send.  Each request is checked here, and answered
{"error": why} when it cannot be served; the table itself takes the lock."""
import logging
from collections.abc import Callable

from mbgw.audit import operator
from mbgw.errors import MbgwError
from mbgw.table.memory import BITS, CONFIG_ZONE, REGISTERS

log = logging.getLogger("mbgw.table")

MAX_OPERATOR_COUNT = 2000            # one reply line stays small; the Modbus bit-read limit
REGISTER_MAX = 0xFFFF


class BadTableRequest(MbgwError):
    """What is wrong with an operator's request, in words for the reply."""


def table_commands(table) -> dict[str, Callable[[dict], dict]]:
    """The control commands of a daemon whose exchange table is `table` (mbgw.table.memory
    Table), for the control server's command dict."""
    def read(request: dict) -> dict:
        return _answer(lambda: _read(table, request))

    def write(request: dict) -> dict:
        return _answer(lambda: _write(table, request))
    return {"table-read": read, "table-write": write}


def while_on(commands: dict[str, Callable[[dict], dict]],
             on: Callable[[], bool]) -> dict[str, Callable[[dict], dict]]:
    """commands, each refusing while on() is false (the daemon's table turned off)."""
    def when_on(command):
        def serve(request: dict) -> dict:
            if not on():
                return {"error": "the exchange table is off (--table, [table] enabled)"}
            return command(request)
        return serve
    return {name: when_on(command) for name, command in commands.items()}


def _answer(serve: Callable[[], dict]) -> dict:
    try:
        return serve()
    except BadTableRequest as err:
        return {"error": str(err)}
    except ValueError as err:        # the table's own refusal (TableError)
        return {"error": f"table: {err}"}


def _integer(request: dict, name: str, default: int | None = None) -> int:
    value = request.get(name, default)
    if value is None:
        raise BadTableRequest(f"table: {name!r} missing")
    if not isinstance(value, int) or isinstance(value, bool):
        raise BadTableRequest(f"table: {name} {value!r} is not an integer")
    return value


def _span(address: int, count: int, size: int, what: str) -> None:
    if not 0 <= address < size:
        raise BadTableRequest(f"table: {what} address {address}: out of range "
                              f"0..{size - 1} (0x0000..0x{size - 1:04X})")
    if not 1 <= count <= MAX_OPERATOR_COUNT:
        raise BadTableRequest(f"table: count {count}: out of range 1..{MAX_OPERATOR_COUNT}")
    if address + count > size:
        raise BadTableRequest(f"table: {what}s {address}..{address + count - 1} run past the "
                              f"last one, {size - 1} (0x{size - 1:04X})")


def _read(table, request: dict) -> dict:
    address = _integer(request, "address")
    count = _integer(request, "count", 1)
    bits = request.get("bits", False)
    if not isinstance(bits, bool):
        raise BadTableRequest(f"table: bits {bits!r} is not true or false")
    _span(address, count, BITS if bits else REGISTERS, "bit" if bits else "register")
    values = table.read_bits(address, count) if bits else table.read(address, count)
    return {"address": address, "bits": bits, "values": list(values)}


def _write(table, request: dict) -> dict:
    address = _integer(request, "address")
    values = request.get("values")
    if not isinstance(values, list) or not values:
        raise BadTableRequest("table: 'values' must be a list of one or more integers")
    _span(address, len(values), REGISTERS, "register")
    for offset, value in enumerate(values):
        if not isinstance(value, int) or isinstance(value, bool):
            raise BadTableRequest(f"table: value {value!r} for register {address + offset} "
                                  f"is not an integer")
        if not 0 <= value <= REGISTER_MAX:
            raise BadTableRequest(f"table: value {value} for register {address + offset} "
                                  f"(0x{address + offset:04X}): out of range 0..65535")
    last = address + len(values) - 1
    if last >= CONFIG_ZONE.start:
        raise BadTableRequest(f"table: register 0x{max(address, CONFIG_ZONE.start):04X} is in "
                              f"the configuration zone 0x8000-0xFFFF, which is read-only")
    table.write(address, values)
    log.info("table: registers 0x%04X..0x%04X written by the operator (%s)", address, last,
             operator(request.get("uid")))
    return {"ok": True, "address": address, "count": len(values)}
