"""How `mbgw status`, `clients` and `stats` print what the daemon reports, in every mode:
the sections put together (each in a render_* module of its own; `mbgw trace`:
mbgw.cli.render_trace)."""
from mbgw.cli.render_lines import (
    cache_section,
    line_devices,
    line_maps,
    lines_section,
    routes_section,
    servers_section,
)
from mbgw.cli.render_modes import master_sections, raw_client, slave_sections, transparent_sections
from mbgw.cli.render_scenarios import format_scenarios
from mbgw.cli.render_table import table_section
from mbgw.cli.render_text import clients_section, clock, duration, load_text


def format_status(s: dict, now: float) -> str:
    lines = [f"mbgw {s['version']}, {s['mode']} mode, pid {s['pid']}, "
             f"up {duration(s['uptime_s'])}", f"location   {s.get('location', '-')}"]
    if s["mode"] == "master":
        lines += master_sections(s, now)
    elif s["mode"] == "transparent":
        lines += [*transparent_sections(s), "", *clients_section(s, now, "table clients")]
    else:
        lines += slave_sections(s, now)
    if len(s.get("lines", ())) > 1 or any(not r["implicit"] for r in s.get("routes", ())):
        lines += ["", *lines_section(s["lines"]), "", *routes_section(s["routes"])]
        # line serial's devices are above (a slave-mode file may leave [serial] out)
        for row in s["lines"][1 if "serial" in s else 0:]:
            lines += ["", *(line_maps(row) if "maps" in row else line_devices(row, now))]
    cached = [row for row in s.get("lines", ()) if row.get("cache")]
    if cached:
        lines += ["", *cache_section(cached)]
    if s.get("servers"):
        lines += ["", *servers_section(s["servers"])]
    if s.get("table") is not None:
        lines += ["", *table_section(s["table"], s["mode"], now, bool(s.get("scenarios")))]
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


STATS_KEYS = ("counters", "counters_since", "line_utilisation_pct", "line_load_pct")


def format_counters(s: dict) -> str:
    """`mbgw stats`: the counters, and the line's load where the mode measures it."""
    load = load_text(s)
    return "\n".join([*([f"line       {load}"] if load else []), *_counters_section(s)])


def _counters_section(s: dict) -> list[str]:
    counters = s["counters"]
    lines = [f"counters since {clock(s['counters_since'])}"]
    names = list(counters)
    for i in range(0, len(names), 3):
        lines.append("  " + "".join(f"{n:<28}{counters[n]:>10}   " for n in names[i:i + 3])
                     .rstrip())
    return lines


def format_clients(s: dict, now: float) -> str:
    """`mbgw clients`: the mode's TCP clients."""
    if s["mode"] == "slave":
        return "\n".join(clients_section(s, now))
    if s["mode"] == "transparent":
        raw = s["transparent"]
        return "\n".join([*clients_section(s, now, "table clients"), "",
                          "raw        off" if raw["raw_port"] is None else
                          f"raw        port {raw['raw_port']}, {raw_client(raw)}"])
    if s.get("tcp_clients") is not None:
        tcp = clients_section({"clients": s["tcp_clients"]}, now)
        if s.get("table") is None:
            return "\n".join(tcp)
        return "\n".join([*tcp, "", *clients_section(s, now, "table clients")])
    if s.get("table") is None:
        return ("master mode: the exchange table is off, so no Modbus TCP clients; its "
                f"connections go to the servers (mbgw status lists them: "
                f"{len(s['upstream']['connections'])} now)")
    return "\n".join(clients_section(s, now, "table clients"))
