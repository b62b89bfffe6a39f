"""A device's rows in `mbgw status`: its health, its exceptions, the demotion rule, its
probes."""
from mbgw.cli.render_text import ago

HEALTH_COLUMNS = (f"  {'ADDR':>4}  {'HEALTH':<8} {'SINCE':<12} {'LAST SUCCESS':<14} "
                  f"{'FAILS':>5} {'REQUESTS':>8} {'REPLIES':>8} {'TIMEOUTS':>8} "
                  f"{'REFUSED':>7}")


def health_row(d: dict, now: float) -> str:
    return (f"  {d['address']:>4}  {d['health']:<8} {ago(d['health_since'], now):<12} "
            f"{ago(d['last_success'], now):<14} {d['consecutive_failures']:>5} "
            f"{d['transactions']:>8} {d['replies']:>8} {d['timeouts']:>8} "
            f"{d['demoted_rejects']:>7}")


def exceptions_text(d: dict) -> str:
    exceptions = " ".join(f"{code}:{n}" for code, n in d["exceptions"].items())
    generated = " ".join(f"{code}:{n}" for code, n in d["gateway_exceptions"].items())
    if generated:
        exceptions = " ".join(filter(None, (exceptions, f"(gateway {generated})")))
    return exceptions or "-"


def demotion_rule(s: dict) -> str:
    """The rule that puts an address down, for the devices' heading."""
    rule = s.get("demotion")
    if not rule:
        return ""
    if not rule["down_after"]:
        return ": never down (down-after 0)"
    return (f": down after {rule['down_after']} failures in a row, then a probe every "
            f"{rule['probe_interval_ms']} ms (doubling while it fails)")


def probe_lines(d: dict) -> list[str]:
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
