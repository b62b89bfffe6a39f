"""How `mbgw trace` prints the daemon's events: a header of columns for the mode, then one
line per request, reply or scenario run (or, with --raw, per burst on the line)."""
import time


def _stamp(moment: float) -> str:
    """HH:MM:SS.mmm, local time."""
    return time.strftime("%H:%M:%S", time.localtime(moment)) + f".{int(moment * 1000) % 1000:03d}"


def trace_columns(mode: str) -> str:
    if mode == "transparent":
        return f"{'TIME':<15} {'DIRECTION':<9} {'LEN':>4}  {'OUTCOME':<10} FRAME (hex)"
    if mode == "master":
        return (f"{'TIME':<15} {'DIRECTION':<9} {'ADDR':>4} {'SERVER':<21} {'TID':>5} "
                f"{'UNIT':>4} {'FC':>4} {'LEN':>4}  OUTCOME")
    return (f"{'TIME':<15} {'DIRECTION':<9} {'CLIENT':<24} {'TID':>5} {'UNIT':>4} "
            f"{'FC':>4} {'LEN':>4}  OUTCOME")


def raw_columns() -> str:
    return f"{'TIME':<15} {'GAP us':>9}  {'KIND':<11} {'LEN':>4}  BYTES (hex)"


def format_raw(e: dict) -> str:
    """A burst on the line (mbgw.line.raw), or the bytes the capture had no room for."""
    stamp = _stamp(e["time"])
    if e["kind"] == "dropped":
        return f"{stamp:<15} {'':>9}  {'dropped':<11} {e['length']:>4}  (not captured)"
    gap = "-" if e.get("gap_us") is None else str(e["gap_us"])
    return f"{stamp:<15} {gap:>9}  {e['kind']:<11} {e['length']:>4}  {e['bytes']}"


def format_event(e: dict) -> str:
    stamp = _stamp(e["time"])
    outcome = e["outcome"]
    if e.get("latency_ms") is not None:
        outcome = f"{outcome} {e['latency_ms']:.1f} ms"
    if e.get("mode") == "transparent":
        return f"{stamp:<15} {e['direction']:<9} {e['length']:>4}  {outcome:<10} {e['frame']}"
    if e.get("mode") == "master":
        tid = "-" if e["tid"] is None else e["tid"]
        unit = "-" if e["unit"] is None else e["unit"]
        address = "-" if e["address"] is None else e["address"]
        where = f"{address:>4} {e['server'] or '-':<21}"
    elif e.get("mode") == "monitor":     # heard on a listen-only line: no client, no tid
        unit = "-" if e["address"] is None else e["address"]
        tid, where = "-", f"{'monitor (heard)':<24}"     # trace names the line after
    elif e.get("scenario") is not None:
        tid, unit, where = "-", e["unit"], f"{'scenario ' + e['scenario']:<24}"
    else:
        face = e.get("face")        # the listeners that are not Modbus TCP say so
        peer = e["peer"] if face in (None, "plain", "tls") else f"{e['peer']} {face}"
        tid, unit, where = e["tid"], e["unit"], f"{peer:<24}"
    return (f"{stamp:<15} {e['direction']:<9} {where} {tid:>5} {unit:>4} "
            f"0x{e['function']:02x} {e['length']:>4}  {outcome}").rstrip()
