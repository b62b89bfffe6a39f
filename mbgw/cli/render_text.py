"""What every status text shares: times (ago, a duration, a clock), the line's load and the
TCP clients' rows."""
import time


def ago(moment: float | None, now: float) -> str:
    if moment is None:
        return "never"
    return f"{duration(now - moment)} ago"


def duration(seconds: float) -> str:
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


def clock(moment: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(moment))


def load_text(s: dict) -> str:
    """'load 12.0 % (10 s), 8.1 % (1 min), 7.9 % on average since ...', or ''."""
    if "line_utilisation_pct" not in s:
        return ""
    load = s.get("line_load_pct") or {}
    recent = ", ".join(f"{load[w]:.1f} % ({w})" for w in ("10s", "1min") if w in load)
    return (f"load {recent + ', ' if recent else ''}{s['line_utilisation_pct']:.1f} % on "
            f"average since {clock(s['counters_since'])}")


def tls_role(client: dict) -> str:
    """'  TLS, role operator' for a Modbus/TCP Security client."""
    if client.get("listener") != "tls":
        return ""
    return f"  TLS, role {client.get('role') or '(none)'}"


def clients_section(s: dict, now: float, title: str = "clients") -> list[str]:
    lines = [f"{title} ({len(s['clients'])})"]
    if s["clients"]:
        lines.append(f"  {'ID':>4}  {'PEER':<24} {'CONNECTED':<19}  {'REQUESTS':>8}  "
                     f"{'IN FLIGHT':>9}  LAST ACTIVITY")
        for c in s["clients"]:
            lines.append(f"  {c['id']:>4}  {c['peer']:<24} {clock(c['connected_since'])}  "
                         f"{c['requests']:>8}  {c['in_flight']:>9}  "
                         f"{ago(c['last_activity'], now)}{tls_role(c)}")
    return lines
