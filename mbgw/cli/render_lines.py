"""The lines, their routes, caches and servers in `mbgw status`, and `mbgw status --line
NAME`."""
from mbgw.cli.render_devices import HEALTH_COLUMNS, health_row


def lines_section(rows: list[dict]) -> list[str]:
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


def cache_section(rows: list[dict]) -> list[str]:
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


def line_devices(row: dict, now: float) -> list[str]:
    out = [f"devices of line {row['name']} ({len(row.get('devices', ()))})"]
    if row.get("devices"):
        out.append(HEALTH_COLUMNS)
        out += [health_row(d, now) for d in row["devices"]]
    return out


def line_maps(row: dict) -> list[str]:
    """A monitor line's [[monitor]] maps, each with its age."""
    out = [f"maps of line {row['name']} ({len(row['maps'])})"]
    out += [f"  monitor {m['map']:<4} " + ("never stored" if m["age_s"] is None else
                                          f"stored {m['age_s']:.1f} s ago") for m in row["maps"]]
    return out


def format_line_status(s: dict, now: float) -> str:
    """line_status()'s, as text."""
    row = s["line"]
    out = [f"mbgw {s['version']}, {s['mode']} mode, pid {s['pid']}", "",
           *lines_section([row]), "",
           *(line_maps(row) if "maps" in row else line_devices(row, now))]
    out += ["", *routes_section(s["routes"]), "", f"counters of line {row['name']}"]
    counters = row["counters"]
    names = [n for n in counters if counters[n]] or list(counters)[:3]
    for i in range(0, len(names), 3):
        out.append("  " + "".join(f"{n:<28}{counters[n]:>10}   " for n in names[i:i + 3])
                   .rstrip())
    return "\n".join(out)


def routes_section(rows: list[dict]) -> list[str]:
    out = ["routes     face    units            target                     rewrite"]
    out += [f"           {r['face']:<7} {r['units']:<16} {r['target']:<26} "
            f"{r['rewrite'] or '-'}{' (implicit)' if r['implicit'] else ''}" for r in rows]
    return out


def servers_section(rows: list[dict]) -> list[str]:
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
