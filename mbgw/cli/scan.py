"""mbgw scan and mbgw probe: commissioning a bus -- which addresses answer at which settings,
and how fast.  DEVICE: a bus no gateway uses (the bus work is mbgw.line.survey's); --line
NAME: the running daemon's line, at its settings (mbgw.cli.daemon_bus)."""
import errno
import json
import math
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Protocol

import click

from mbgw.cli.daemon_bus import DaemonBus
from mbgw.cli.diag import control_option
from mbgw.cli.options import Failure, convert
from mbgw.config.model import LineFormat, SerialConfig
from mbgw.config.number_list import parse_number_list
from mbgw.errors import ConfigError, SerialError
from mbgw.line.holder import device_holders
from mbgw.line.survey import (
    READ_BASIC_IDENTITY,
    READ_REGISTER_0,
    REPORT_SERVER_ID,
    Answer,
    Bus,
)
from mbgw.protocol.device_identity import identification_objects, server_id
from mbgw.protocol.pdu import EXCEPTION_FLAG, MAX_SERIAL_ADDRESS

DEFAULT_BAUDRATES = "9600,19200,38400,57600,115200"
DEFAULT_FORMATS = "8e1,8n1,8o1,8n2"
TIMING_READS = 5               # scan: the reads that time a unit found
TIMING_TIMEOUT_MS = 1000       # each of them, and each identity request
MIN_STOUT_MS = 20              # probe recommends at least this
STOUT_PER_P99 = 1.5


class Surveyed(Protocol):
    """What scan and probe ask: a Bus of their own, or the daemon's line (DaemonBus)."""

    def ask(self, unit: int, pdu: bytes, timeout_ms: int) -> Answer | None: ...

    def tune(self, cfg: SerialConfig) -> None: ...


def _baudrates(text: str) -> list[int]:
    rates = [item for item in text.replace(" ", ",").split(",") if item]
    if not rates or not all(item.isdigit() for item in rates):
        raise ConfigError(f"{text!r}: expected baud rates, e.g. 9600,19200")
    return [int(rate) for rate in rates]


def _formats(text: str) -> list[LineFormat]:
    shapes = [LineFormat.parse(item) for item in text.replace(" ", ",").split(",") if item]
    if not shapes:
        raise ConfigError(f"{text!r}: expected formats, e.g. 8e1,8n1")
    return shapes


def _settings(baudrates: str, formats: str, device: str) -> list[SerialConfig]:
    """Every baud rate × format, in the order given (baud rate first)."""
    shapes = _formats(formats)
    return [SerialConfig(device, rate, shape) for rate in _baudrates(baudrates)
            for shape in shapes]


def _units(text: str) -> tuple[int, ...]:
    return parse_number_list("units", text, 1, MAX_SERIAL_ADDRESS)


def _percentile(sorted_ms: Sequence[float], share: float) -> float:
    """Nearest rank: the smallest value at or above share of them."""
    return sorted_ms[max(0, math.ceil(share * len(sorted_ms)) - 1)]


def _timing(times_ns: list[int]) -> tuple[float | None, float | None]:
    """(p50, p99) in ms, None without any time."""
    if not times_ns:
        return None, None
    ms = sorted(t / 1e6 for t in times_ns)
    return round(_percentile(ms, 0.5), 1), round(_percentile(ms, 0.99), 1)


@contextmanager
def _opened(cfg: SerialConfig) -> Iterator[Bus]:
    """The bus at cfg's settings; exit 1 naming who holds the device when it is in use."""
    try:
        bus = Bus(cfg)
    except SerialError as err:
        if err.errno == errno.EBUSY:
            holders = ", ".join(device_holders(cfg.device)) or "another program"
            raise Failure(f"{cfg.device} is in use by {holders}") from None
        raise Failure(str(err)) from None
    try:
        yield bus
    except SerialError as err:        # the device gone meanwhile
        raise Failure(str(err)) from None
    finally:
        bus.close()


class _Progress:
    """One line rewritten on stderr, when stderr is a terminal."""

    def __init__(self) -> None:
        self.on = sys.stderr.isatty()

    def show(self, text: str) -> None:
        if self.on:
            click.echo(f"\r\033[K{text}", err=True, nl=False)

    def clear(self) -> None:
        if self.on:
            click.echo("\r\033[K", err=True, nl=False)


def _identity(bus: Surveyed, unit: int) -> dict | None:
    """FC 43/14's basic objects, else FC 17's server id, else None."""
    answer = bus.ask(unit, READ_BASIC_IDENTITY, TIMING_TIMEOUT_MS)
    objects = identification_objects(answer.pdu) if answer is not None else None
    if objects is not None:
        return objects
    answer = bus.ask(unit, REPORT_SERVER_ID, TIMING_TIMEOUT_MS)
    return server_id(answer.pdu) if answer is not None else None


def _found(bus: Surveyed, unit: int, cfg: SerialConfig, answer: Answer) -> dict:
    """What scan reports of a unit that answered at cfg."""
    times = [got.response_ns for got in
             (bus.ask(unit, READ_REGISTER_0, TIMING_TIMEOUT_MS) for _ in range(TIMING_READS))
             if got is not None]
    p50, p99 = _timing(times)
    exception = answer.pdu[1] if answer.pdu[0] & EXCEPTION_FLAG and len(answer.pdu) > 1 \
        else None
    return {"unit": unit, "baudrate": cfg.baudrate, "format": str(cfg.format),
            "exception": exception, "p50_ms": p50, "p99_ms": p99,
            "identity": _identity(bus, unit)}


def scan_bus(bus: Surveyed, settings: list[SerialConfig], units: Sequence[int],
             timeout_ms: int, first: bool, progress: _Progress) -> list[dict]:
    """Each setting in turn (bus at the first already), each unit not found yet at each."""
    found: list[dict] = []
    answered: set[int] = set()
    for index, cfg in enumerate(settings):
        if index:
            bus.tune(cfg)
        for unit in units:
            if unit in answered:
                continue
            progress.show(f"{cfg.baudrate} {cfg.format}: unit {unit}, "
                          f"{len(found)} found")
            answer = bus.ask(unit, READ_REGISTER_0, timeout_ms)
            if answer is None:
                continue
            answered.add(unit)
            found.append(_found(bus, unit, cfg, answer))
            if first:
                return found
    return found


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f} ms"


def scan_row(row: dict) -> str:
    identity = row["identity"] or {}
    said = ", ".join(f"{key} {value!r}" for key, value in identity.items()) or "no identity"
    exception = "" if row["exception"] is None else f", exception {row['exception']:02x}"
    return (f"unit {row['unit']}: {row['baudrate']} {row['format']}{exception}, "
            f"p50 {_ms(row['p50_ms'])}, p99 {_ms(row['p99_ms'])}, {said}")


def recommended_stout(p99_ms: float) -> int:
    return max(MIN_STOUT_MS, math.ceil(p99_ms * STOUT_PER_P99))


def probe_unit(bus: Surveyed, unit: int, count: int, timeout_ms: int) -> dict:
    times = []
    for _ in range(count):
        got = bus.ask(unit, READ_REGISTER_0, timeout_ms)
        if got is not None:
            times.append(got.response_ns)
    p50, p99 = _timing(times)
    return {"unit": unit, "reads": count, "answered": len(times), "p50_ms": p50,
            "p99_ms": p99, "stout_ms": None if p99 is None else recommended_stout(p99)}


def probe_row(row: dict) -> str:
    text = f"unit {row['unit']}: {row['reads']} reads, {row['answered']} answered"
    if row["p99_ms"] is None:
        return text
    return (f"{text}, p50 {row['p50_ms']:.1f} ms, p99 {row['p99_ms']:.1f} ms, "
            f"recommended stout {row['stout_ms']} ms")


def _only_the_lines(line_cfg: SerialConfig, baudrates: str | None, formats: str | None,
                    hints: tuple[str, str]) -> None:
    """--line: --baudrates/--formats (hints: those options' names) may name only the line's
    own settings: the daemon does not change a running line's."""
    rate_hint, format_hint = hints
    if baudrates is not None and \
            convert(rate_hint, lambda: _baudrates(baudrates)) != [line_cfg.baudrate]:
        raise click.BadParameter(
            f"line at {line_cfg.baudrate}: the daemon does not change a running line's baud "
            f"rate (leave {rate_hint} out)", param_hint=rate_hint)
    if formats is not None and \
            convert(format_hint, lambda: _formats(formats)) != [line_cfg.format]:
        raise click.BadParameter(
            f"line at {line_cfg.format}: the daemon does not change a running line's format "
            f"(leave {format_hint} out)", param_hint=format_hint)


def _device_or_line(device: str | None, line: str | None) -> None:
    if (device is None) == (line is None):
        raise click.UsageError("give DEVICE or --line NAME (exactly one)")


def _echo_rows(rows: list[dict], as_json: bool, row_text) -> None:
    if as_json:
        click.echo(json.dumps(rows))
    else:
        for row in rows:
            click.echo(row_text(row))


line_option = click.option(
    "--line", metavar="NAME",
    help="Instead of DEVICE: the running daemon's line NAME (in slave mode), asked between "
         "its transactions at its own settings.")


def register(main: click.Group) -> None:
    @main.command()
    @click.argument("device", required=False)
    @line_option
    @click.option("--baudrates", metavar="LIST",
                  help=f"The baud rates to try, in this order [default: {DEFAULT_BAUDRATES}; "
                       f"with --line: the line's].")
    @click.option("--formats", metavar="LIST",
                  help=f"The formats to try at each baud rate, in this order [default: "
                       f"{DEFAULT_FORMATS}; with --line: the line's].")
    @click.option("--units", default="1-247", show_default=True, metavar="RANGES",
                  help="The addresses to ask, e.g. 1-10,17.")
    @click.option("--timeout", "timeout_ms", default=100, show_default=True,
                  type=click.IntRange(1, 60000), metavar="MS",
                  help="How long each address has to answer.")
    @click.option("--first", is_flag=True, help="End after the first address that answers.")
    @click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
    @control_option
    def scan(device: str | None, line: str | None, baudrates: str | None,
             formats: str | None, units: str, timeout_ms: int, first: bool, as_json: bool,
             control: str | None, instance: str | None) -> None:
        """Find the addresses that answer on a serial bus, and their settings: each baud
        rate, then each format, then each address, asked FC 3 register 0 (an exception reply
        is an answer too).  An address found is timed (5 reads) and asked its identity (FC
        43/14, else FC 17), and not asked again at other settings.  DEVICE: a bus no gateway
        uses; --line NAME: the running daemon's line, one read in each of its turns, at the
        line's settings only.  Exit status 0 when an address answered, 1 when none did or
        the device is in use."""
        _device_or_line(device, line)
        unit_list = convert("'--units'", lambda: _units(units))
        progress = _Progress()
        try:
            if line is not None:
                bus = DaemonBus(control, instance, line)
                settings = [bus.settings()]
                _only_the_lines(settings[0], baudrates, formats,
                                ("'--baudrates'", "'--formats'"))
                found = scan_bus(bus, settings, unit_list, timeout_ms, first, progress)
            else:
                assert device is not None
                settings = convert("'--baudrates'/'--formats'", lambda: _settings(
                    baudrates or DEFAULT_BAUDRATES, formats or DEFAULT_FORMATS, device))
                with _opened(settings[0]) as own:
                    found = scan_bus(own, settings, unit_list, timeout_ms, first, progress)
        finally:
            progress.clear()
        _echo_rows(found, as_json, scan_row)
        if not found:
            raise Failure(f"no address answered on {device or 'line ' + str(line)}")

    @main.command()
    @click.argument("device", required=False)
    @line_option
    @click.option("--units", required=True, metavar="LIST",
                  help="The addresses to measure, e.g. 1,5,17.")
    @click.option("--count", default=100, show_default=True, type=click.IntRange(1, 100000),
                  help="Reads (FC 3 register 0) per address.")
    @click.option("--baudrate", type=int,
                  help="The line's baud rate [default: 9600; with --line: the line's].")
    @click.option("--format", "line_format", metavar="FORMAT",
                  help="The line's data bits, parity, stop bits [default: 8n1; with --line: "
                       "the line's].")
    @click.option("--timeout", "timeout_ms", default=1000, show_default=True,
                  type=click.IntRange(1, 60000), metavar="MS",
                  help="How long each read may take.")
    @click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
    @control_option
    def probe(device: str | None, line: str | None, units: str, count: int,
              baudrate: int | None, line_format: str | None, timeout_ms: int, as_json: bool,
              control: str | None, instance: str | None) -> None:
        """Measure each address's response time over --count reads and print the stout it
        recommends: p99 x 1.5 rounded up, at least 20 ms.  DEVICE: a bus no gateway uses;
        --line NAME: the running daemon's line, one read in each of its turns.  Exit status
        0 when an address answered, 1 when none did or the device is in use."""
        _device_or_line(device, line)
        unit_list = convert("'--units'", lambda: _units(units))
        if line is not None:
            bus = DaemonBus(control, instance, line)
            _only_the_lines(bus.settings(), None if baudrate is None else str(baudrate),
                            line_format, ("'--baudrate'", "'--format'"))
            rows = [probe_unit(bus, unit, count, timeout_ms) for unit in unit_list]
        else:
            assert device is not None
            cfg = convert(None, lambda: SerialConfig(
                device, baudrate or 9600, LineFormat.parse(line_format or "8n1")))
            with _opened(cfg) as own:
                rows = [probe_unit(own, unit, count, timeout_ms) for unit in unit_list]
        _echo_rows(rows, as_json, probe_row)
        if not any(row["answered"] for row in rows):
            raise Failure(f"no address answered on {device or 'line ' + str(line)}")
