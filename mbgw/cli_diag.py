"""Operator commands that talk to the running daemon: status, clients close, stats reset,
trace.  Registered on the main group by mbgw.cli."""
import json
import sys
import time

import click

from mbgw import control as ctl

control_option = click.option(
    "--control", metavar="PATH", default=None,
    help="The daemon's control socket [default: $RUNTIME_DIRECTORY/mbgw.sock or "
         "/run/mbgw/mbgw.sock; for mbgw@NAME: /run/mbgw/NAME/mbgw.sock].")


def _call(path: str | None, request: dict) -> dict:
    path = path or ctl.default_path()
    try:
        reply = ctl.call(path, request)
    except PermissionError:
        _fail(f"permission denied on {path}: run it as root or as a member of the service's "
              f"group (e.g. sudo mbgw {request['command']})")
    except (FileNotFoundError, ConnectionRefusedError):
        _fail(f"no mbgw daemon answers on {path} (is it running? --control PATH)")
    except OSError as err:
        _fail(f"{path}: {err.strerror or err}")
    if "error" in reply:
        _fail(reply["error"])
    return reply


def _fail(message: str):
    click.echo(f"mbgw: {message}", err=True)
    sys.exit(1)


def _ago(moment: float | None, now: float) -> str:
    if moment is None:
        return "never"
    return f"{_duration(now - moment)} ago"


def _duration(seconds: float) -> str:
    seconds = max(seconds, 0)
    if seconds < 60:
        return f"{seconds:.1f}s"
    minutes, secs = divmod(int(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    days, hours = divmod(hours, 24)
    if days:
        return f"{days}d{hours:02d}h{minutes:02d}m"
    if hours:
        return f"{hours}h{minutes:02d}m"
    return f"{minutes}m{secs:02d}s"


def _clock(moment: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(moment))


def format_status(s: dict, now: float) -> str:
    serial = s["serial"]
    lines = [
        f"mbgw {s['version']}, {s['mode']} mode, pid {s['pid']}, up {_duration(s['uptime_s'])}",
        f"listening  {', '.join(s['listening'])}",
        f"serial     {serial['device']} {serial['baudrate']} {serial['format']} "
        f"{serial['protocol']} {serial['interface']}, stout {serial['stout_ms']} ms: "
        f"line {serial['state']}, queue {s['queue_depth']}, "
        f"utilisation {s['line_utilisation_pct']:.1f} %",
        "",
        f"clients ({len(s['clients'])})",
    ]
    if s["clients"]:
        lines.append(f"  {'ID':>4}  {'PEER':<24} {'CONNECTED':<19}  {'REQUESTS':>8}  "
                     f"{'IN FLIGHT':>9}  LAST ACTIVITY")
        for c in s["clients"]:
            lines.append(f"  {c['id']:>4}  {c['peer']:<24} {_clock(c['connected_since'])}  "
                         f"{c['requests']:>8}  {c['in_flight']:>9}  "
                         f"{_ago(c['last_activity'], now)}")
    lines += ["", f"devices ({len(s['devices'])})"]
    if s["devices"]:
        lines.append(f"  {'ADDR':>4}  {'HEALTH':<8} {'SINCE':<12} {'LAST SUCCESS':<14} "
                     f"{'FAILS':>5} {'REQUESTS':>8} {'REPLIES':>8} {'TIMEOUTS':>8} "
                     f"{'CRC':>5} {'OTHER':>5}  EXCEPTIONS")
        for d in s["devices"]:
            other = d["invalid_frames"] + d["wrong_unit"] + d["wrong_function"] + \
                d["late_replies"]
            exceptions = " ".join(f"{code}:{n}" for code, n in d["exceptions"].items())
            generated = " ".join(f"{code}:{n}" for code, n in d["gateway_exceptions"].items())
            if generated:
                exceptions = " ".join(filter(None, (exceptions, f"(gateway {generated})")))
            lines.append(f"  {d['address']:>4}  {d['health']:<8} "
                         f"{_ago(d['health_since'], now):<12} "
                         f"{_ago(d['last_success'], now):<14} {d['consecutive_failures']:>5} "
                         f"{d['transactions']:>8} {d['replies']:>8} {d['timeouts']:>8} "
                         f"{d['crc_errors']:>5} {other:>5}  {exceptions or '-'}")
    counters = s["counters"]
    lines += ["", f"counters since {_clock(s['counters_since'])}"]
    names = list(counters)
    for i in range(0, len(names), 3):
        lines.append("  " + "".join(f"{n:<28}{counters[n]:>10}   " for n in names[i:i + 3])
                     .rstrip())
    return "\n".join(lines)


def register(main: click.Group) -> None:
    @main.command()
    @click.option("--json", "as_json", is_flag=True, help="Print the status as JSON.")
    @control_option
    def status(as_json: bool, control: str | None) -> None:
        """What the running daemon is doing: clients, devices, counters."""
        reply = _call(control, {"command": "status"})
        if as_json:
            click.echo(json.dumps(reply, indent=2))
        else:
            click.echo(format_status(reply, time.time()))

    @main.group()
    def clients() -> None:
        """The Modbus TCP clients of the running daemon."""

    @clients.command("close")
    @click.argument("client_id", type=int, metavar="ID")
    @control_option
    def close(client_id: int, control: str | None) -> None:
        """Force-close client ID (the ID column of mbgw status)."""
        _call(control, {"command": "close", "client": client_id})
        click.echo(f"client {client_id} closed")

    @main.group()
    def stats() -> None:
        """The running daemon's counters."""

    @stats.command("reset")
    @control_option
    def reset(control: str | None) -> None:
        """Zero every counter (logged by the daemon)."""
        _call(control, {"command": "reset"})
        click.echo("counters reset")

    @main.command()
    @click.option("--pcap", "pcap_file", type=click.File("wb"), default=None, metavar="FILE",
                  help="Also write the traffic to FILE as a Modbus/TCP pcap capture "
                       "(Wireshark, tshark; '-' for standard output).")
    @click.option("--count", type=click.IntRange(1), default=None,
                  help="Stop after this many events [default: until Ctrl-C].")
    @control_option
    def trace(pcap_file, count: int | None, control: str | None) -> None:
        """Live, decoded view of the traffic through the running daemon."""
        from mbgw.pcap import PcapWriter

        path = control or ctl.default_path()
        try:
            sock = ctl.connect(path, timeout=None)
        except PermissionError:
            _fail(f"permission denied on {path}: run it as root or as a member of the "
                  f"service's group (e.g. sudo mbgw trace)")
        except (FileNotFoundError, ConnectionRefusedError):
            _fail(f"no mbgw daemon answers on {path} (is it running? --control PATH)")
        writer = PcapWriter(pcap_file) if pcap_file else None
        echo = (lambda text: click.echo(text, err=True)) if pcap_file and \
            pcap_file.name == "<stdout>" else click.echo
        seen = 0
        with sock, sock.makefile("rb") as events:
            sock.sendall(b'{"command": "trace"}\n')
            events.readline()          # {"listening": [...]}
            echo(f"{'TIME':<15} {'DIRECTION':<9} {'CLIENT':<24} {'TID':>5} {'UNIT':>4} "
                 f"{'FC':>4} {'LEN':>4}  OUTCOME")
            try:
                for line in events:
                    event = json.loads(line)
                    echo(format_event(event))
                    if writer is not None:
                        writer.write_event(event)
                    seen += 1
                    if count is not None and seen >= count:
                        break
            except KeyboardInterrupt:
                pass


def format_event(e: dict) -> str:
    stamp = time.strftime("%H:%M:%S", time.localtime(e["time"])) + \
        f".{int(e['time'] * 1000) % 1000:03d}"
    outcome = e["outcome"]
    if e.get("latency_ms") is not None:
        outcome = f"{outcome} {e['latency_ms']:.1f} ms"
    return (f"{stamp:<15} {e['direction']:<9} {e['peer']:<24} {e['tid']:>5} {e['unit']:>4} "
            f"0x{e['function']:02x} {e['length']:>4}  {outcome}").rstrip()
