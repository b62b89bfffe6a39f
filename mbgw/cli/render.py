"""How `mbgw status`, `clients`, `stats` and `scenarios` print what the daemon reports, in
every mode (`mbgw trace`: mbgw.cli.render_trace)."""
import time


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


# --- mbgw status ---------------------------------------------------------------------------

def format_status(s: dict, now: float) -> str:
    lines = [f"mbgw {s['version']}, {s['mode']} mode, pid {s['pid']}, "
             f"up {_duration(s['uptime_s'])}", f"location   {s.get('location', '-')}"]
    if s["mode"] == "master":
        lines += _master_sections(s, now)
    elif s["mode"] == "transparent":
        lines += [*_transparent_sections(s), "", *_clients_section(s, now, "table clients")]
    else:
        lines += _slave_sections(s, now)
    if len(s.get("lines", ())) > 1 or any(not r["implicit"] for r in s.get("routes", ())):
        lines += ["", *_lines_section(s["lines"]), "", *_routes_section(s["routes"])]
        # line serial's devices are above (a slave-mode file may leave [serial] out)
        for row in s["lines"][1 if "serial" in s else 0:]:
            lines += ["", *(_line_maps(row) if "maps" in row else _line_devices(row, now))]
    cached = [row for row in s.get("lines", ()) if row.get("cache")]
    if cached:
        lines += ["", *_cache_section(cached)]
    if s.get("servers"):
        lines += ["", *_servers_section(s["servers"])]
    if s.get("table") is not None:
        lines += ["", *_table_section(s["table"], s["mode"], now, bool(s.get("scenarios")))]
    elif s.get("scenarios"):
        lines += ["", "table      on (scenarios): no Modbus client reaches it (table.enabled "
                      "off)"]
    if s.get("firewall") is not None:
        lines += ["", *_firewall_section(s["firewall"])]
    if s.get("scenarios"):
        lines += ["", *format_scenarios(s["scenarios"], now)]
    if s.get("mqtt"):
        lines += ["", _mqtt_line(s["mqtt"])]
    lines += ["", *_counters_section(s)]
    return "\n".join(lines)


def _mqtt_line(m: dict) -> str:
    return (f"mqtt       {m['broker']} {m['profile']} node {m['node']}: "
            f"{'connected' if m['connected'] else 'not connected'}, "
            f"{m['messages_sent']} sent, {m['messages_dropped']} dropped, {m['writes']} "
            f"writes, {m['commands_refused']} commands refused")


def _lines_section(rows: list[dict]) -> list[str]:
    """The daemon's lines (more than one, or routes of the file's)."""
    out = ["lines      name          state    requests  replies  timeouts  device"]
    out += [f"           {r['name']:<13} {r['state']:<8} {r['requests']:>8} {r['replies']:>8} "
            f"{r['timeouts']:>9}  {r['device']} ({r['mode']}{_connection(r)})" for r in rows]
    return out


def _connection(row: dict) -> str:
    """A remote line's figures of its connection, after its mode."""
    counters = row.get("counters") or {}
    if "reconnects" not in counters:
        return ""
    return f", {counters['reconnects']} reconnects, {counters['stray_replies']} stray replies"


def _cache_section(rows: list[dict]) -> list[str]:
    """The read cache's figures of each line that has served or missed, by unit."""
    out = ["cache      line          unit      hits  coalesced   misses  stale"]
    for row in rows:
        for unit, f in row["cache"]["units"].items():
            out.append(f"           {row['name']:<13} {unit:>4} {f['hits']:>9} "
                       f"{f['coalesced']:>10} {f['misses']:>8} {f['stale_served']:>6}")
    return out


def line_status(s: dict, name: str) -> dict:
    """`mbgw status --line NAME`: that line's row and the routes from or to it.  A
    LookupError names a line the daemon does not have, and those it has."""
    rows = s.get("lines") or []
    if not rows:
        raise LookupError(f"status --line {name}: {s['mode']} mode shows no lines: mbgw "
                          f"status shows its one line")
    for row in rows:
        if row["name"] == name:
            routes = [r for r in s.get("routes", ())
                      if r["face"] == name or r["target"] == f"line {name}"]
            return {"mode": s["mode"], "version": s["version"], "pid": s["pid"],
                    "line": row, "routes": routes}
    known = ", ".join(r["name"] for r in rows)
    raise LookupError(f"status --line {name}: no such line (this daemon's lines: {known})")


def _line_devices(row: dict, now: float) -> list[str]:
    out = [f"devices of line {row['name']} ({len(row.get('devices', ()))})"]
    if row.get("devices"):
        out.append(_HEALTH_COLUMNS)
        out += [_health(d, now) for d in row["devices"]]
    return out


def _line_maps(row: dict) -> list[str]:
    """A monitor line's [[monitor]] maps, each with its age."""
    out = [f"maps of line {row['name']} ({len(row['maps'])})"]
    out += [f"  monitor {m['map']:<4} " + ("never stored" if m["age_s"] is None else
                                          f"stored {m['age_s']:.1f} s ago") for m in row["maps"]]
    return out


def format_line_status(s: dict, now: float) -> str:
    """line_status()'s, as text."""
    row = s["line"]
    out = [f"mbgw {s['version']}, {s['mode']} mode, pid {s['pid']}", "",
           *_lines_section([row]), "",
           *(_line_maps(row) if "maps" in row else _line_devices(row, now))]
    out += ["", *_routes_section(s["routes"]), "", f"counters of line {row['name']}"]
    counters = row["counters"]
    names = [n for n in counters if counters[n]] or list(counters)[:3]
    for i in range(0, len(names), 3):
        out.append("  " + "".join(f"{n:<28}{counters[n]:>10}   " for n in names[i:i + 3])
                   .rstrip())
    return "\n".join(out)


def _servers_section(rows: list[dict]) -> list[str]:
    """The remote Modbus TCP servers the TCP face's routes reach (slave mode)."""
    out = [f"servers ({len(rows)})",
           f"  {'SERVER':<21} {'REQUESTS':>8} {'REPLIES':>8} {'EXCEPT':>6} {'TIMEOUTS':>8} "
           f"{'UNREACH':>7} {'OPEN':>4} {'OPENED':>6} {'LOST':>4}"]
    for r in rows:
        c = r["counters"]
        out.append(f"  {r['server']:<21} {c['requests']:>8} {c['replies']:>8} "
                   f"{c['device_exceptions']:>6} {c['timeouts']:>8} {c['unreachable']:>7} "
                   f"{len(r['connections']):>4} {c['connections_opened']:>6} "
                   f"{c['connections_lost']:>4}")
    return out


def _routes_section(rows: list[dict]) -> list[str]:
    out = ["routes     face    units            target                     rewrite"]
    out += [f"           {r['face']:<7} {r['units']:<16} {r['target']:<26} "
            f"{r['rewrite'] or '-'}{' (implicit)' if r['implicit'] else ''}" for r in rows]
    return out


STATS_KEYS = ("counters", "counters_since", "line_utilisation_pct", "line_load_pct")


def format_counters(s: dict) -> str:
    """`mbgw stats`: the counters, and the line's load where the mode measures it."""
    load = _load(s)
    return "\n".join([*([f"line       {load}"] if load else []), *_counters_section(s)])


def _counters_section(s: dict) -> list[str]:
    counters = s["counters"]
    lines = [f"counters since {_clock(s['counters_since'])}"]
    names = list(counters)
    for i in range(0, len(names), 3):
        lines.append("  " + "".join(f"{n:<28}{counters[n]:>10}   " for n in names[i:i + 3])
                     .rstrip())
    return lines


def _load(s: dict) -> str:
    """'load 12.0 % (10 s), 8.1 % (1 min), 7.9 % on average since ...', or ''."""
    if "line_utilisation_pct" not in s:
        return ""
    load = s.get("line_load_pct") or {}
    recent = ", ".join(f"{load[w]:.1f} % ({w})" for w in ("10s", "1min") if w in load)
    return (f"load {recent + ', ' if recent else ''}{s['line_utilisation_pct']:.1f} % on "
            f"average since {_clock(s['counters_since'])}")


def format_clients(s: dict, now: float) -> str:
    """`mbgw clients`: the mode's TCP clients."""
    if s["mode"] == "slave":
        return "\n".join(_clients_section(s, now))
    if s["mode"] == "transparent":
        raw = s["transparent"]
        return "\n".join([*_clients_section(s, now, "table clients"), "",
                          "raw        off" if raw["raw_port"] is None else
                          f"raw        port {raw['raw_port']}, {_raw_client(raw)}"])
    if s.get("tcp_clients") is not None:
        tcp = _clients_section({"clients": s["tcp_clients"]}, now)
        if s.get("table") is None:
            return "\n".join(tcp)
        return "\n".join([*tcp, "", *_clients_section(s, now, "table clients")])
    if s.get("table") is None:
        return ("master mode: the exchange table is off, so no Modbus TCP clients; its "
                f"connections go to the servers (mbgw status lists them: "
                f"{len(s['upstream']['connections'])} now)")
    return "\n".join(_clients_section(s, now, "table clients"))


def _clients_section(s: dict, now: float, title: str = "clients") -> list[str]:
    lines = [f"{title} ({len(s['clients'])})"]
    if s["clients"]:
        lines.append(f"  {'ID':>4}  {'PEER':<24} {'CONNECTED':<19}  {'REQUESTS':>8}  "
                     f"{'IN FLIGHT':>9}  LAST ACTIVITY")
        for c in s["clients"]:
            lines.append(f"  {c['id']:>4}  {c['peer']:<24} {_clock(c['connected_since'])}  "
                         f"{c['requests']:>8}  {c['in_flight']:>9}  "
                         f"{_ago(c['last_activity'], now)}{_tls_role(c)}")
    return lines


def _transparent_sections(s: dict) -> list[str]:
    t = s["transparent"]
    eof = f"char 0x{t['eof_char']:02x}" if t["eof"] == "char" else t["eof"]
    raw = "off" if t["raw_port"] is None else f"port {t['raw_port']}, {_raw_client(t)}"
    return [f"{_line(s['serial'])}: line {_state(s['serial'])}",
            f"frames     eof {eof}, eof-timeout {t['eof_timeout_ms']} ms, crc "
            f"{'on' if t['crc'] else 'off'}, trigger {'on' if t['trigger'] else 'off'}, "
            f"silence {t['silence_ms']} ms",
            f"areas      rx {t['rx_address']}+{t['rx_size']} bytes, tx {t['tx_address']}+"
            f"{t['tx_size']} bytes",
            f"raw        {raw}"]


def _raw_client(t: dict) -> str:
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


def _exceptions(d: dict) -> str:
    exceptions = " ".join(f"{code}:{n}" for code, n in d["exceptions"].items())
    generated = " ".join(f"{code}:{n}" for code, n in d["gateway_exceptions"].items())
    if generated:
        exceptions = " ".join(filter(None, (exceptions, f"(gateway {generated})")))
    return exceptions or "-"


def _demotion(s: dict) -> str:
    """The rule that puts an address down, for the devices' heading."""
    rule = s.get("demotion")
    if not rule:
        return ""
    if not rule["down_after"]:
        return ": never down (down-after 0)"
    return (f": down after {rule['down_after']} failures in a row, then a probe every "
            f"{rule['probe_interval_ms']} ms (doubling while it fails)")


def _next_probe(d: dict) -> list[str]:
    """The lines under a device: its own timing ([[device]]); when it fails, why, when bytes
    came but no valid reply; when a request may go to it as a probe, while it is down."""
    lines = [f"        {d['diagnosis']}"] if d.get("diagnosis") else []
    timing = d.get("timing")
    if timing:
        lines.append(f"        own timing: stout {timing['stout_ms']} ms, retries "
                     f"{timing['retries']}, pause {timing['pause_ms']} ms, down after "
                     f"{timing['down_after']}, probe every {timing['probe_interval_ms']} ms")
    if d.get("probe_timeout_ms") is not None:
        p99 = d.get("learnt_p99_ms")
        learnt = "no answer yet" if p99 is None else f"{p99:.1f} ms"
        lines.append(f"        learnt p99 {learnt}, probe timeout "
                     f"{d['probe_timeout_ms']:.1f} ms")
    wait = d.get("next_probe_in_s")
    return lines if wait is None else lines + [f"        next probe in {wait:.1f} s"]


def _health(d: dict, now: float) -> str:
    return (f"  {d['address']:>4}  {d['health']:<8} {_ago(d['health_since'], now):<12} "
            f"{_ago(d['last_success'], now):<14} {d['consecutive_failures']:>5} "
            f"{d['transactions']:>8} {d['replies']:>8} {d['timeouts']:>8} "
            f"{d['demoted_rejects']:>7}")


_HEALTH_COLUMNS = (f"  {'ADDR':>4}  {'HEALTH':<8} {'SINCE':<12} {'LAST SUCCESS':<14} "
                   f"{'FAILS':>5} {'REQUESTS':>8} {'REPLIES':>8} {'TIMEOUTS':>8} "
                   f"{'REFUSED':>7}")


def _firewall_section(f: dict) -> list[str]:
    """The firewall: refusals by rule and by client."""
    lines = [f"firewall   {len(f['rules'])} rules, default {f['default']}: "
             f"{f['refused']} requests refused"]
    for rule in f["rules"]:
        lines.append(f"  {rule['selects']:<56} {rule['refused']:>8} refused")
    lines.append(f"  {'no rule (default ' + f['default'] + ')':<56} "
                 f"{f['refused_default']:>8} refused")
    if f.get("require_role"):
        lines.append(f"  {'TLS client without a role (require-role)':<56} "
                     f"{f['refused_no_role']:>8} refused")
    for client in f["clients"]:
        if client["refused"]:
            lines.append(f"  client {client['peer']} (role {client['role'] or 'none'}): "
                         f"{client['refused']} refused")
    return lines


def _slave_sections(s: dict, now: float) -> list[str]:
    serial = s.get("serial")
    if serial is None:      # [serial] left out: the [[line]]s follow
        return [f"listening  {', '.join(s['listening'])}", "", *_clients_section(s, now)]
    lines = [
        f"listening  {', '.join(s['listening'])}",
        f"{_line(serial)}, stout {serial['stout_ms']} ms: line {_state(serial)}, "
        f"queue {s['queue_depth']}",
        f"           {_load(s)}",
        *_faces(s.get("faces")),
        "",
        *_clients_section(s, now),
    ]
    lines += ["", f"devices ({len(s['devices'])}){_demotion(s)}"]
    if s["devices"]:
        lines.append(f"{_HEALTH_COLUMNS} {'CRC':>5} {'OTHER':>5}  EXCEPTIONS")
        for d in s["devices"]:
            other = d["invalid_frames"] + d["wrong_unit"] + d["wrong_function"] + \
                d["late_replies"]
            lines.append(f"{_health(d, now)} {d['crc_errors']:>5} {other:>5}  "
                         f"{_exceptions(d)}")
            lines += _next_probe(d)
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


def _master_sections(s: dict, now: float) -> list[str]:
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
                  *_clients_section({"clients": s["tcp_clients"]}, now)]
    lines += ["", f"upstream connections ({len(up['connections'])})"]
    if up["connections"]:
        lines.append(f"  {'SERVER':<21} {'LOCAL':<21} {'CONNECTED':<19}  {'REQUESTS':>8}  "
                     f"{'UNITS':<12} LAST ACTIVITY")
        for c in up["connections"]:
            units = ",".join(map(str, c["units"])) or "-"
            lines.append(f"  {c['server']:<21} {c['local']:<21} "
                         f"{_clock(c['connected_since'])}  {c['requests']:>8}  {units:<12} "
                         f"{_ago(c['last_activity'], now)}{_tls_role(c)}")
    if s.get("table") is not None:
        lines += ["", *_clients_section(s, now, "table clients")]
    lines += ["", f"devices ({len(s['devices'])}){_demotion(s)}"]
    if s["devices"]:
        lines.append(f"{_HEALTH_COLUMNS} {'UNREACH':>7} {'INVALID':>7} {'ABANDON':>7}  "
                     f"{'SERVER':<15} {'UNIT':>4}  EXCEPTIONS")
        for d in s["devices"]:
            host, unit = (d["upstream"]["host"], d["upstream"]["unit"]) \
                if d.get("upstream") else ("*", 0)
            invalid = d["wrong_unit"] + d["wrong_function"] + d["invalid_frames"]
            lines.append(f"{_health(d, now)} {d['unreachable']:>7} {invalid:>7} "
                         f"{d['abandoned']:>7}  {host:<15} {unit:>4}  {_exceptions(d)}")
            lines += _next_probe(d)
    return lines


_TABLE_OUTCOMES = ("answered", "exception", "broadcast")


def _table_section(t: dict, mode: str, now: float, scenarios: bool = False) -> list[str]:
    """The exchange table: what reaches it, requests by function, exceptions sent, master
    mode's serial slave, the persistence.  Off (table.enabled), it still runs for the
    scenarios when there are any."""
    if t.get("enabled") is False and not scenarios:
        return ["table      off"]
    lines = [f"table      {_table_reach(t, mode)}" if t.get("enabled") is not False else
             "table      on (scenarios): no Modbus client reaches it (table.enabled off)"]
    rows = [(fc, row) for fc, row in t.get("requests", {}).items() if any(row.values())]
    if rows:
        lines.append(f"  {'FC':>4}  " + "  ".join(f"{o.upper():>9}" for o in _TABLE_OUTCOMES))
        lines += [f"  {fc:>4}  " + "  ".join(f"{row.get(o, 0):>9}" for o in _TABLE_OUTCOMES)
                  for fc, row in rows]
    else:
        lines.append("  no requests yet")
    if t.get("exceptions"):
        lines.append("  exceptions sent " + " ".join(f"{code}:{n}"
                                                    for code, n in t["exceptions"].items()))
    serial = t.get("serial")
    if serial is not None:
        lines.append(f"  serial slave: {serial.get('requests', 0)} requests, "
                     f"{serial.get('crc_errors', 0)} invalid CRC, "
                     f"{serial.get('length_errors', 0)} invalid length, "
                     f"{serial.get('send_failures', 0)} failed sends")
    tcp = t.get("tcp")
    if tcp is not None:
        lines.append(f"  TCP server: {tcp.get('connections', 0)} of "
                     f"{tcp.get('max_connections', '-')} clients, "
                     f"{tcp.get('connections_accepted', 0)} accepted, "
                     f"{tcp.get('connections_refused_limit', 0)} refused (limit), "
                     f"{tcp.get('connections_bad_header', 0)} closed (bad header)")
        if tcp.get("tls_port") is not None:
            lines.append(f"  TLS on port {tcp['tls_port']}: "
                         f"{tcp.get('tls_handshakes', 0)} handshakes under way, "
                         f"{tcp.get('connections_refused_tls', 0)} refused, "
                         f"{tcp.get('connections_tls_probes', 0)} closed before a byte")
    persist = t.get("persist")
    if persist is not None:
        lines.append(f"  persist {_table_persist(persist, now)}")
        if persist.get("failing"):
            lines.append(f"  persist FAILING since {_ago(persist.get('failing_since'), now)}: "
                         f"{persist['failing']} (changes since the last save are not kept)")
    return lines


def _table_reach(t: dict, mode: str) -> str:
    parts = []
    if mode == "master" and "address" in t:
        parts.append(f"serial address {t['address']}" if t["address"] else "no serial address")
        parts.append(f"TCP port {t['port']}")
    elif "units" in t:
        parts.append(f"units {t['units']} (direct)" if t["direct"] else
                     "every unit (no direct messaging)")
    if "functions" in t:
        parts.append("functions " + ",".join(map(str, t["functions"])))
    return ", ".join(parts) or "on"


def _table_persist(persist: dict, now: float) -> str:
    """'PATH: last save 3.0s ago, saves 4, ...': every figure the persistence reports."""
    figures = []
    for name, value in persist.items():
        if name in ("path", "failing", "failing_since"):
            continue
        if name.startswith("last_"):
            value = _ago(value, now)
        if name == "interval_s":
            name, value = "every", f"{value:g}s"
        figures.append(f"{name.replace('_', ' ')} {value}")
    return f"{persist.get('path', '-')}: {', '.join(figures)}" if figures else \
        str(persist.get("path", "-"))


# --- the scenarios (mbgw status, mbgw scenarios) ---------------------------------------------

def format_scenarios(rows: list[dict], now: float) -> list[str]:
    """One line per scenario, then its message (an error's, or why it waits)."""
    if not rows:
        return ["scenarios  none"]
    lines = [f"scenarios ({len(rows)})",
             f"  {'NAME':<16} {'STATE':<9} {'TARGET':<24} {'FC':>2} {'TRIGGER':<8} "
             f"{'RUNS':>7} {'ERRORS':>6} {'RETRY':>5} {'OVERRUN':>7} {'LATENCY':>8}  "
             f"{'DATA AGE':<9} LAST SUCCESS"]
    for r in rows:
        latency = "-" if r["last_latency_ms"] is None else f"{r['last_latency_ms']:.1f}ms"
        age = "-" if r["data_age_s"] is None else _duration(r["data_age_s"])
        if r.get("stale"):
            age += " stale"
        lines.append(f"  {r['name']:<16} {r['state']:<9} {r['target']:<24} "
                     f"{r['function']:>2} {r['trigger']:<8} {r['runs']:>7} "
                     f"{sum(r['errors'].values()):>6} {r['retries']:>5} {r['overruns']:>7} "
                     f"{latency:>8}  {age:<9} {_ago(r['last_success'], now)}")
        if r["message"]:
            probe = r.get("next_probe_in_s")
            lines.append(f"    {'error: ' if r['state'] == 'error' else ''}{r['message']}" +
                         ("" if probe is None else f", next probe in {probe:.1f} s"))
    return lines


def _tls_role(client: dict) -> str:
    """'  TLS, role operator' for a Modbus/TCP Security client."""
    if client.get("listener") != "tls":
        return ""
    return f"  TLS, role {client.get('role') or '(none)'}"
