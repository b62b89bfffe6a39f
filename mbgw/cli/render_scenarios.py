"""The scenarios, in `mbgw status` and `mbgw scenarios`."""
from mbgw.cli.render_text import ago, duration


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
        age = "-" if r["data_age_s"] is None else duration(r["data_age_s"])
        if r.get("stale"):
            age += " stale"
        lines.append(f"  {r['name']:<16} {r['state']:<9} {r['target']:<24} "
                     f"{r['function']:>2} {r['trigger']:<8} {r['runs']:>7} "
                     f"{sum(r['errors'].values()):>6} {r['retries']:>5} {r['overruns']:>7} "
                     f"{latency:>8}  {age:<9} {ago(r['last_success'], now)}")
        if r["message"]:
            probe = r.get("next_probe_in_s")
            lines.append(f"    {'error: ' if r['state'] == 'error' else ''}{r['message']}" +
                         ("" if probe is None else f", next probe in {probe:.1f} s"))
    return lines
