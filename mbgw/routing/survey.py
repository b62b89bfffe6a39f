"""`mbgw scan --line NAME` and `mbgw probe --line NAME` on the control socket: the running
daemon's line in slave mode asked one survey read at a time, in the line's own turns
(routing.queue.SurveyRead through the line's Inbox), at the line's settings.

"survey-line" {"line"}: the line's settings ({"line", "device", "baudrate", "format"}).
"survey-read" {"line", "unit", "pdu" (hex), "timeout_ms"}: {"pdu": hex or null (no reply in
time), "response_ns"}.  A line that is not there, not in slave mode, not RTU or down is
{"error": why}."""
import asyncio
import logging
import time
from collections.abc import Callable
from typing import NamedTuple

from mbgw.audit import operator
from mbgw.config.model import SerialConfig
from mbgw.ops.control import BadRequest
from mbgw.ops.trace import Outcome
from mbgw.protocol.pdu import MAX_SERIAL_ADDRESS
from mbgw.routing.queue import Inbox, SurveyRead

SOURCE = "survey"           # every survey read's one turn in the line's round robin
MAX_TIMEOUT_MS = 60000
MAX_PDU = 253
# A read waits for its turn behind the clients' transactions (each up to stout with its
# retries) before its own timeout: the control call gives up after this much more.
TURN_WAIT_S = 120.0


class SurveyLine(NamedTuple):
    """A line the daemon can survey: a line in slave mode, its inbox and settings."""
    inbox: Inbox
    serial: SerialConfig


# name -> the line, or the mode of a line that cannot be surveyed ("master", "monitor")
Lines = Callable[[], dict[str, "SurveyLine | str"]]


log = logging.getLogger("mbgw.line")


def survey_commands(lines: Lines) -> dict[str, Callable]:
    """The control commands over the daemon's lines (lines(): as they are now, after any
    reload)."""
    def line_settings(request: dict) -> dict:
        try:
            name, line = _line(lines(), request)
        except BadRequest as why:
            return {"error": str(why)}
        s = line.serial
        log.info("line %s: surveyed (mbgw scan or probe --line) by %s", name,
                 operator(request.get("uid")))
        return {"line": name, "device": s.device, "baudrate": s.baudrate,
                "format": str(s.format)}

    async def read(request: dict) -> dict:
        try:
            name, line = _line(lines(), request)
            unit, request_pdu, timeout_ms = _read_request(request)
        except BadRequest as why:
            return {"error": str(why)}
        return await _ask(name, line.inbox, unit, request_pdu, timeout_ms)

    return {"survey-line": line_settings, "survey-read": read}


def _line(lines: dict, request: dict) -> tuple[str, SurveyLine]:
    name = request.get("line")
    if not isinstance(name, str):
        raise BadRequest('expected {"line": NAME}')
    line = lines.get(name)
    if line is None:
        raise BadRequest(f"no line {name!r} (lines: {', '.join(sorted(lines))})")
    if isinstance(line, str):
        raise BadRequest(f"line {name} is in {line} mode: only a line in slave mode (mbgw "
                            f"its master) can be scanned through the daemon")
    if line.serial.protocol != "rtu":
        raise BadRequest(f"line {name} is an {line.serial.protocol.upper()} line: scan "
                            f"and probe ask RTU lines only")
    return name, line


def _read_request(request: dict) -> tuple[int, bytes, int]:
    unit, hex_pdu, timeout_ms = (request.get(key) for key in ("unit", "pdu", "timeout_ms"))
    if not isinstance(unit, int) or not 1 <= unit <= MAX_SERIAL_ADDRESS:
        raise BadRequest(f'"unit": expected 1 to {MAX_SERIAL_ADDRESS}')
    if not isinstance(timeout_ms, int) or not 1 <= timeout_ms <= MAX_TIMEOUT_MS:
        raise BadRequest(f'"timeout_ms": expected 1 to {MAX_TIMEOUT_MS}')
    try:
        request_pdu = bytes.fromhex(hex_pdu) if isinstance(hex_pdu, str) else b""
    except ValueError:
        request_pdu = b""
    if not 1 <= len(request_pdu) <= MAX_PDU:
        raise BadRequest(f'"pdu": expected 1 to {MAX_PDU} bytes in hex')
    return unit, request_pdu, timeout_ms


async def _ask(name: str, inbox: Inbox, unit: int, request_pdu: bytes,
               timeout_ms: int) -> dict:
    """One survey read on the line's thread; its answer as the command's reply."""
    loop = asyncio.get_running_loop()
    answered: asyncio.Future = loop.create_future()

    def done(exchange, reply: bytes | None, outcome: str) -> None:      # the line's thread
        loop.call_soon_threadsafe(_settle, answered, (exchange, reply, outcome))

    inbox.submit(SurveyRead(SOURCE, unit, request_pdu, time.monotonic_ns(), done, timeout_ms))
    try:
        survey, reply, outcome = await asyncio.wait_for(answered,
                                                        timeout_ms / 1000 + TURN_WAIT_S)
    except TimeoutError:
        return {"error": f"line {name}: the read got no turn in {TURN_WAIT_S:g} s"}
    if outcome == Outcome.TIMEOUT:
        return {"pdu": None, "response_ns": 0}
    if outcome in (Outcome.REPLY, Outcome.DEVICE_EXCEPTION) and reply is not None:
        return {"pdu": reply.hex(), "response_ns": survey.response_ns}
    return {"error": f"line {name}: {outcome}"}


def _settle(future: asyncio.Future, result: tuple) -> None:
    if not future.done():          # the command gave up meanwhile
        future.set_result(result)
