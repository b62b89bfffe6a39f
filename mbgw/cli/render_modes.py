"""Each mode's own sections of `mbgw status`: slave mode's line, faces and devices, master
mode's servers, slaveid table and devices, transparent mode's frames and areas."""
from mbgw.cli.render_devices import (
    HEALTH_COLUMNS,
    demotion_rule,
    exceptions_text,
    health_row,
    probe_lines,
)
from mbgw.cli.render_text import ago, clients_section, clock, load_text, tls_role


def slave_sections(s: dict, now: float) -> list[str]:
    serial = s.get("serial")
    if serial is None:      # [serial] left out: the [[line]]s follow
        return [f"listening  {', '.join(s['listening'])}", "", *clients_section(s, now)]
    lines = [
        f"listening  {', '.join(s['listening'])}",
        f"{_line(serial)}, stout {serial['stout_ms']} ms: line {_state(serial)}, "
        f"queue {s['queue_depth']}",
        f"           {load_text(s)}",
        *_faces(s.get("faces")),
        "",
        *clients_section(s, now),
    ]
    lines += ["", f"devices ({len(s['devices'])}){demotion_rule(s)}"]
    if s["devices"]:
        lines.append(f"{HEALTH_COLUMNS} {'CRC':>5} {'OTHER':>5}  EXCEPTIONS")
        for d in s["devices"]:
            other = d["invalid_frames"] + d["wrong_unit"] + d["wrong_function"] + \
                d["late_replies"]
            lines.append(f"{health_row(d, now)} {d['crc_errors']:>5} {other:>5}  "
                         f"{exceptions_text(d)}")
            lines += probe_lines(d)
    return lines


def _faces(faces: dict | None) -> list[str]:
    """What came in by each listener, once a Modbus/UDP or RTU-over-TCP one has had any."""
    if not faces or not any(any(faces[f].values()) for f in ("udp", "rtu") if f in faces):
        return []
    said = []
    for listener, f in faces.items():
        if any(f.values()):
            extra = [f"{f['refused']} refused"] if f["refused"] else []
            extra += [f"{f['retransmissions']} again"] if f["retransmissions"] else []
            extra += [f"{f['bad_frames']} bad frames"] if f["bad_frames"] else []
            extra += [f"{f['dropped']} dropped"] if f["dropped"] else []
            clients = f"{f['clients']} client{'' if f['clients'] == 1 else 's'}"
            said.append(f"{listener} {clients}, {f['requests']} requests" +
                        (f" ({', '.join(extra)})" if extra else ""))
    return [f"faces      {'; '.join(said)}"]


def master_sections(s: dict, now: float) -> list[str]:
    up = s["upstream"]
    lines = [
        f"{_line(s['serial'])}: line {_state(s['serial'])}",
        f"servers    port {up['port']}, tcpto {up['tcpto_ms']} ms, exception "
        f"{'on' if up['exception'] else 'off'}, at most {up['max_connections']} connections",
    ]
    table = s.get("table") or {}     # None while the table is off
    table_address = table.get("address") if table.get("enabled") else None
    routes = [r["route"] for r in s["slaveid"]] or [
        f"empty: only the table's address {table_address} is answered" if table_address
        else "empty: every request is ignored"]
    lines += [f"{'slaveid' if i == 0 else '':<10} {route}" for i, route in enumerate(routes)]
    if s.get("listening") is not None:
        lines += [f"listening  {', '.join(s['listening'])} (the Modbus TCP face)",
                  *_faces(s.get("faces")), "",
                  *clients_section({"clients": s["tcp_clients"]}, now)]
    lines += ["", f"upstream connections ({len(up['connections'])})"]
    if up["connections"]:
        lines.append(f"  {'SERVER':<21} {'LOCAL':<21} {'CONNECTED':<19}  {'REQUESTS':>8}  "
                     f"{'UNITS':<12} LAST ACTIVITY")
        for c in up["connections"]:
            units = ",".join(map(str, c["units"])) or "-"
            lines.append(f"  {c['server']:<21} {c['local']:<21} "
                         f"{clock(c['connected_since'])}  {c['requests']:>8}  {units:<12} "
                         f"{ago(c['last_activity'], now)}{tls_role(c)}")
    if s.get("table") is not None:
        lines += ["", *clients_section(s, now, "table clients")]
    lines += ["", f"devices ({len(s['devices'])}){demotion_rule(s)}"]
    if s["devices"]:
        lines.append(f"{HEALTH_COLUMNS} {'UNREACH':>7} {'INVALID':>7} {'ABANDON':>7}  "
                     f"{'SERVER':<15} {'UNIT':>4}  EXCEPTIONS")
        for d in s["devices"]:
            host, unit = (d["upstream"]["host"], d["upstream"]["unit"]) \
                if d.get("upstream") else ("*", 0)
            invalid = d["wrong_unit"] + d["wrong_function"] + d["invalid_frames"]
            lines.append(f"{health_row(d, now)} {d['unreachable']:>7} {invalid:>7} "
                         f"{d['abandoned']:>7}  {host:<15} {unit:>4}  {exceptions_text(d)}")
            lines += probe_lines(d)
    return lines


def transparent_sections(s: dict) -> list[str]:
    t = s["transparent"]
    eof = f"char 0x{t['eof_char']:02x}" if t["eof"] == "char" else t["eof"]
    raw = "off" if t["raw_port"] is None else f"port {t['raw_port']}, {raw_client(t)}"
    return [f"{_line(s['serial'])}: line {_state(s['serial'])}",
            f"frames     eof {eof}, eof-timeout {t['eof_timeout_ms']} ms, crc "
            f"{'on' if t['crc'] else 'off'}, trigger {'on' if t['trigger'] else 'off'}, "
            f"silence {t['silence_ms']} ms",
            f"areas      rx {t['rx_address']}+{t['rx_size']} bytes, tx {t['tx_address']}+"
            f"{t['tx_size']} bytes",
            f"raw        {raw}"]


def raw_client(t: dict) -> str:
    if not t["raw_client"]:
        return "client none"
    return f"client {t['raw_client']}" + ("" if t.get("raw_client_sending", True) else
                                          " (done sending: it gets the frames until it goes "
                                          "or another client comes)")


def _line(serial: dict) -> str:
    protocol = f"{serial['protocol']} " if "protocol" in serial else ""   # none: transparent
    return (f"serial     {serial['device']} {serial['baudrate']} {serial['format']} "
            f"{protocol}{serial['interface']}")


def _state(serial: dict) -> str:
    """The line's state; "waiting": nothing at the device's path yet."""
    if serial["state"] == "waiting":
        return "down, waiting for the device to appear"
    return serial["state"]
