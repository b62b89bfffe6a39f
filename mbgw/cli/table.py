"""`mbgw table read` and `mbgw table write`: the operator reads and writes the running
daemon's exchange table through its control socket (mbgw.table.control answers)."""
import json

import click

from mbgw.cli.diag import ask, control_option
from mbgw.cli.options import Failure
from mbgw.table.control import MAX_OPERATOR_COUNT, REGISTER_MAX


class Number(click.ParamType):
    """A decimal or 0x-hexadecimal integer in 0..high."""
    name = "number"

    def __init__(self, high: int) -> None:
        self.high = high

    def convert(self, value, param, ctx) -> int:
        if isinstance(value, int):
            number = value
        else:
            text = str(value).strip().lower()
            try:
                number = int(text[2:], 16) if text.startswith("0x") else int(text, 10)
            except ValueError:
                self.fail(f"{value!r} is not a number (decimal, or hexadecimal as 0x1A2B)",
                          param, ctx)
        if not 0 <= number <= self.high:
            self.fail(f"{value} is out of range 0..{self.high} (0x{self.high:X})", param, ctx)
        return number


ADDRESS = Number(0xFFFF)
VALUE = Number(REGISTER_MAX)


def register_line(address: int, value: int) -> str:
    return f"0x{address:04X}  {value:5d}  0x{value:04X}"


def bit_line(address: int, value: int) -> str:
    return f"0x{address:04X}  {value}"


def _ask(control: str | None, instance: str | None, request: dict) -> dict:
    try:
        return ask(control, instance, request)
    except Failure as failure:
        if f"unknown command {request['command']!r}" in failure.message:
            raise Failure("the daemon serves no exchange table (start it with --table, or "
                          "set table.enabled in its file)") from None
        raise


def register(main: click.Group) -> None:
    @main.group()
    def table() -> None:
        """Read and write the running daemon's exchange table (--table): registers 0x0000-
        0xFFFF, of which 0x8000-0xFFFF (the configuration zone) are read-only."""

    @table.command("read")
    @click.argument("address", type=ADDRESS, metavar="ADDR")
    @click.argument("count", type=click.IntRange(1, MAX_OPERATOR_COUNT), default=1,
                    required=False)
    @click.option("--bits", is_flag=True,
                  help="Read bits (as FC 1/2): bit ADDR is bit ADDR%16 of register ADDR/16.")
    @click.option("--json", "as_json", is_flag=True, help="Print the reply as JSON.")
    @control_option
    def read(address: int, count: int, bits: bool, as_json: bool, control: str | None,
             instance: str | None) -> None:
        """Print COUNT registers (default 1) from ADDR (decimal or 0x hex), one line each:
        address, value in decimal and in hex; with --bits, COUNT bits, address and 0 or 1."""
        reply = _ask(control, instance, {"command": "table-read", "address": address,
                                         "count": count, "bits": bits})
        if as_json:
            click.echo(json.dumps(reply, indent=2))
            return
        line = bit_line if bits else register_line
        for offset, value in enumerate(reply["values"]):
            click.echo(line(address + offset, value))

    @table.command("write")
    @click.argument("address", type=ADDRESS, metavar="ADDR")
    @click.argument("values", type=VALUE, nargs=-1, required=True, metavar="VALUE...")
    @control_option
    def write(address: int, values: tuple[int, ...], control: str | None,
              instance: str | None) -> None:
        """Write registers from ADDR (decimal or 0x hex): one VALUE (0..65535, decimal or 0x
        hex) each, all at once, as FC 16 would.  Not in the configuration zone
        (0x8000-0xFFFF).  Logged by the daemon with your uid."""
        reply = _ask(control, instance, {"command": "table-write", "address": address,
                                         "values": list(values)})
        last = address + reply.get("count", len(values)) - 1
        span = f"register 0x{address:04X}" if last == address else \
            f"registers 0x{address:04X}..0x{last:04X}"
        click.echo(f"{span} written")
