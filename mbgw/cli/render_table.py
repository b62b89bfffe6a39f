"""The exchange table's section of `mbgw status`."""
from mbgw.cli.render_text import ago

_TABLE_OUTCOMES = ("answered", "exception", "broadcast")
# (the status key, what its count is said to be)
_SERIAL_SLAVE = (("requests", "requests"), ("crc_errors", "invalid CRC"),
                 ("length_errors", "invalid length"), ("send_failures", "failed sends"))
_TCP_SERVER = (("connections_accepted", "accepted"),
               ("connections_refused_limit", "refused (limit)"),
               ("connections_bad_header", "closed (bad header)"))
_TLS = (("tls_handshakes", "handshakes under way"), ("connections_refused_tls", "refused"),
        ("connections_tls_probes", "closed before a byte"))


def table_section(t: dict, mode: str, now: float, scenarios: bool = False) -> list[str]:
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
        lines.append("  serial slave: " + _counts(serial, _SERIAL_SLAVE))
    tcp = t.get("tcp")
    if tcp is not None:
        lines.append(f"  TCP server: {tcp.get('connections', 0)} of "
                     f"{tcp.get('max_connections', '-')} clients, " + _counts(tcp, _TCP_SERVER))
        if tcp.get("tls_port") is not None:
            lines.append(f"  TLS on port {tcp['tls_port']}: " + _counts(tcp, _TLS))
    persist = t.get("persist")
    if persist is not None:
        lines.append(f"  persist {_table_persist(persist, now)}")
        if persist.get("failing"):
            lines.append(f"  persist FAILING since {ago(persist.get('failing_since'), now)}: "
                         f"{persist['failing']} (changes since the last save are not kept)")
    return lines


def _counts(block: dict, words: tuple[tuple[str, str], ...]) -> str:
    """'9 requests, 1 invalid CRC, ...': each count of block (0 when it has none) and what it
    is."""
    return ", ".join(f"{block.get(key, 0)} {word}" for key, word in words)


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
            value = ago(value, now)
        if name == "interval_s":
            name, value = "every", f"{value:g}s"
        figures.append(f"{name.replace('_', ' ')} {value}")
    return f"{persist.get('path', '-')}: {', '.join(figures)}" if figures else \
        str(persist.get("path", "-"))
