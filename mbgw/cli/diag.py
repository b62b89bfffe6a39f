"""Operator commands that talk to the running daemon: status, clients [close], stats
[reset], trace.  Registered on the main group by mbgw.cli."""
import json
import time
from typing import NoReturn

import click

from mbgw.cli.file_options import check_instance
from mbgw.cli.options import Failure
from mbgw.cli.render import STATS_KEYS, format_clients, format_counters, format_status
from mbgw.cli.render_lines import format_line_status, line_status
from mbgw.cli.render_trace import format_event, format_raw, raw_columns, trace_columns
from mbgw.ops import control as ctl


def control_option(function):
    """--control PATH and -i/--instance NAME: the daemon to talk to."""
    function = click.option(
        "-i", "--instance", metavar="NAME",
        help="The daemon of the service instance mbgw@NAME, on "
             "/run/mbgw/NAME/mbgw.sock.")(function)
    return click.option(
        "--control", metavar="PATH", default=None,
        help="The daemon's control socket [default: $RUNTIME_DIRECTORY/mbgw.sock or "
             "/run/mbgw/mbgw.sock].")(function)


def _socket_path(control: str | None, instance: str | None) -> str:
    if instance is None:
        return control or ctl.default_path()
    if control is not None:
        raise click.UsageError("give --control or --instance, not both")
    return ctl.instance_path(check_instance(instance))


def _call(path: str, request: dict, timeout: float = 5.0) -> dict:
    try:
        reply = ctl.call(path, request, timeout)
    except PermissionError:
        _fail(f"permission denied on {path}: run it as root or as a member of the service's "
              f"group (e.g. sudo mbgw {request['command']})")
    except (FileNotFoundError, ConnectionRefusedError):
        _fail(f"no mbgw daemon answers on {path} (is it running? --control PATH or -i NAME)")
    except TimeoutError:
        _fail(f"{path}: no reply within {timeout:g} s")
    except OSError as err:
        _fail(f"{path}: {err.strerror or err}")
    if "error" in reply:
        _fail(reply["error"])
    return reply


def ask(control: str | None, instance: str | None, request: dict,
        timeout: float = 5.0) -> dict:
    """Send one request to the daemon of --control/-i; its reply, or a Failure saying why
    there is none (or the daemon's error)."""
    return _call(_socket_path(control, instance), request, timeout)


def _host(peer: str) -> str:
    """The IP of a peer "IP:PORT" or "[IPv6]:PORT"."""
    return peer.rsplit(":", 1)[0].strip("[]")


def _fail(message: str) -> NoReturn:
    raise Failure(message)


def _close(path: str, which: str | None, close_all: bool) -> None:
    """mbgw clients close: by ID, else every client whose address or IP is which (all)."""
    if which is not None and which.isdigit():
        _call(path, {"command": "close", "client": int(which)})
        click.echo(f"client {which} closed")
        return
    listed = _call(path, {"command": "status"})
    if "clients" not in listed:
        _call(path, {"command": "close", "client": 0})    # the mode's own refusal
    chosen = [c for c in listed["clients"]
              if close_all or which in (c["peer"], _host(c["peer"]))]
    if which is not None and not chosen:
        peers = ", ".join(c["peer"] for c in listed["clients"]) or "none"
        _fail(f"no client at {which} (clients: {peers})")
    for c in chosen:
        _call(path, {"command": "close", "client": c["id"]})
        click.echo(f"client {c['id']} ({c['peer']}) closed")
    if not chosen:
        click.echo("no clients")


def _trace(path: str, request: dict, raw: bool, pcap_file, count: int | None) -> None:
    """mbgw trace: the daemon's events, shown (and written to pcap_file) until count."""
    from mbgw.cli.pcap import PcapWriter

    try:
        sock = ctl.connect(path, timeout=None)
    except PermissionError:
        _fail(f"permission denied on {path}: run it as root or as a member of the "
              f"service's group (e.g. sudo mbgw trace)")
    except (FileNotFoundError, ConnectionRefusedError):
        _fail(f"no mbgw daemon answers on {path} (is it running? --control PATH or "
              f"-i NAME)")
    writer = PcapWriter(pcap_file) if pcap_file else None
    echo = (lambda text: click.echo(text, err=True)) if pcap_file and \
        pcap_file.name == "<stdout>" else click.echo
    seen = 0
    with sock, sock.makefile("rb") as events:
        sock.sendall(json.dumps(request).encode() + b"\n")
        header = json.loads(events.readline() or b"{}")     # {"mode": ..., ...}
        if "error" in header:
            if header["error"].startswith("trace: line "):
                _fail(f"--line: {header['error']}")     # exit 1, as status --line
            _fail(header["error"])
        echo(raw_columns() if raw else trace_columns(header.get("mode", "slave")))
        named = len(header.get("lines", ())) > 1     # each event's line, when there are more
        try:
            for line_text in events:
                event = json.loads(line_text)
                text = format_raw(event) if raw else format_event(event)
                if named and event.get("line") is not None:
                    text = f"{text}  line {event['line']}"
                echo(text)
                if writer is not None and event.get("mode") != "transparent":
                    writer.write_event(event)     # raw frames are not Modbus/TCP; a
                    #                               scenario's run has no TCP ends
                seen += 1
                if count is not None and seen >= count:
                    break
        except KeyboardInterrupt:
            pass


def _status(path: str, as_json: bool, line: str | None) -> None:
    """mbgw status: the daemon's, or one line's (an unknown line fails naming the known)."""
    reply = _call(path, {"command": "status"})
    if line is not None:
        try:
            reply = line_status(reply, line)
        except LookupError as err:
            _fail(str(err))
    if as_json:
        click.echo(json.dumps(reply, indent=2))
    elif line is not None:
        click.echo(format_line_status(reply, time.time()))
    else:
        click.echo(format_status(reply, time.time()))


@click.command()
@click.option("--json", "as_json", is_flag=True, help="Print the status as JSON.")
@click.option("--line", default=None, metavar="NAME",
              help="Only this line: its state, counters, devices and routes (serial or a "
                   "[[line]] name).")
@control_option
def status(as_json: bool, line: str | None, control: str | None,
           instance: str | None) -> None:
    """What the running daemon is doing: clients, devices, counters; its lines and
    routes."""
    _status(_socket_path(control, instance), as_json, line)


@click.group(invoke_without_command=True)
@control_option
@click.pass_context
def clients(ctx: click.Context, control: str | None, instance: str | None) -> None:
    """The Modbus TCP clients of the running daemon: listed without a subcommand;
    `clients close` closes them."""
    if ctx.invoked_subcommand is None:
        click.echo(format_clients(_call(_socket_path(control, instance),
                                        {"command": "status"}), time.time()))


@clients.command("close")
@click.argument("which", required=False, metavar="ID|ADDRESS")
@click.option("--all", "close_all", is_flag=True, help="Close every client.")
@control_option
def close(which: str | None, close_all: bool, control: str | None,
          instance: str | None) -> None:
    """Force-close a client: its ID (the ID column of mbgw clients), its address
    IP:PORT, or an IP (every client from it); --all: every client."""
    if (which is None) == (not close_all):
        raise click.UsageError("give an ID, an ADDRESS or --all (one of them)")
    _close(_socket_path(control, instance), which, close_all)


@click.group(invoke_without_command=True)
@click.option("--json", "as_json", is_flag=True, help="Print the counters as JSON.")
@control_option
@click.pass_context
def stats(ctx: click.Context, as_json: bool, control: str | None,
          instance: str | None) -> None:
    """The running daemon's counters: shown without a subcommand; `stats reset` zeroes
    them."""
    if ctx.invoked_subcommand is not None:
        return
    reply = _call(_socket_path(control, instance), {"command": "status"})
    if as_json:
        click.echo(json.dumps({k: reply[k] for k in STATS_KEYS if k in reply}, indent=2))
    else:
        click.echo(format_counters(reply))


@stats.command("reset")
@control_option
def reset(control: str | None, instance: str | None) -> None:
    """Zero every counter (logged by the daemon)."""
    _call(_socket_path(control, instance), {"command": "reset"})
    click.echo("counters reset")


@click.command()
@click.option("--pcap", "pcap_file", type=click.File("wb"), default=None, metavar="FILE",
              help="Also write the traffic to FILE as a Modbus/TCP pcap capture "
                   "(Wireshark, tshark; '-' for standard output): the TCP clients' "
                   "requests and replies; scenario runs and the raw line are not in it.")
@click.option("--raw", is_flag=True,
              help="Show the serial line's raw bytes instead: every burst sent and "
                   "received in hex, the silence before it (us), and what it was "
                   "(request, reply, noise, unsolicited).  The daemon captures them "
                   "only while someone watches.")
@click.option("--unit", type=click.IntRange(0, 255), default=None,
              help="Only this unit id (serial address).")
@click.option("--client", "client_id", type=click.IntRange(1), default=None,
              metavar="ID", help="Only this client (the ID column of mbgw status).")
@click.option("--function", type=click.IntRange(1, 127), default=None, metavar="FC",
              help="Only this function code (its exception replies included).")
@click.option("--scenario", default=None, metavar="NAME",
              help="Only this scenario's runs.")
@click.option("--line", default=None, metavar="NAME",
              help="Only this line's traffic: serial or a [[line]] name (mbgw status "
                   "lists them).")
@click.option("--errors", is_flag=True,
              help="Errors only: exception replies, no reply, late replies, noise on "
                   "the line.")
@click.option("--count", type=click.IntRange(1), default=None,
              help="Stop after this many events [default: until Ctrl-C].")
@control_option
def trace(pcap_file, raw: bool, unit: int | None, client_id: int | None,
          function: int | None, scenario: str | None, line: str | None, errors: bool,
          count: int | None, control: str | None, instance: str | None) -> None:
    """Live, decoded view of the traffic through the running daemon: the TCP clients'
    requests and the scenarios' runs (marked with the scenario's name)."""
    if raw and pcap_file:
        raise click.UsageError("--pcap writes Modbus/TCP frames: not with --raw")
    if raw and (unit is not None or client_id is not None or function is not None or
                scenario is not None):
        raise click.UsageError("--raw shows bytes: it takes --line and --errors only")
    wanted = {"unit": unit, "client": client_id, "function": function,
              "scenario": scenario, "line": line, "errors": errors}
    request = {"command": "trace", "raw": raw,
               "filters": {k: v for k, v in wanted.items() if v not in (None, False)}}
    _trace(_socket_path(control, instance), request, raw, pcap_file, count)


def register(main: click.Group) -> None:
    for command in (status, clients, stats, trace):
        main.add_command(command)
