"""What the running transparent-mode daemon reports through the control socket (the commands
every mode shares are in mbgw.ops.status)."""
import logging
import time

from mbgw.audit import Kind, event, operator
from mbgw.ops.status import DaemonStatus
from mbgw.scenarios.report import scenarios_status

log = logging.getLogger("mbgw.control")


class TransparentStatus(DaemonStatus):
    """Transparent mode: the frame settings, the counters, the raw client, the table."""
    mode = "transparent"

    def __init__(self, cfg, line, counters, table_figures, raw, server) -> None:
        """server: the table's (mbgw.table.server.TableServer), whose clients are listed."""
        super().__init__(cfg, counters, None, line.trace)
        self._server = server
        self._line = line
        self._table_figures = table_figures
        self._raw = raw
        self.scenario_engines: dict = {}    # the TCP scenarios' engine (the daemon's)

    def figures(self) -> dict:
        """The mode's own part: the settings in force, the raw port."""
        t = self.cfg.transparent
        raw = self._raw
        return {"eof": t.eof, "eof_char": t.eof_char,
                "eof_timeout_ms": t.eof_timeout_for(self.cfg.serial),
                "rx_address": t.rx_address, "rx_size": t.rx_size,
                "tx_address": t.tx_address, "tx_size": t.tx_size, "crc": t.crc,
                "trigger": t.trigger, "silence_ms": t.silence_ms,
                "raw_port": None if raw is None else raw.port,
                "raw_client": None if raw is None or raw.client is None else raw.peer,
                "raw_client_sending": raw is not None and raw.reading}

    def status(self, request: dict) -> dict:
        data = self._common()
        data["serial"]["state"] = self._line.state
        del data["serial"]["protocol"]     # frames pass as they are: no Modbus framing here
        rows = scenarios_status(self.scenario_engines.values())
        return {**data, "transparent": self.figures(), "counters": self._counters.snapshot(),
                "counters_since": self._reset_at, "table": self._table_figures(),
                "clients": self._server.clients(),
                **({"scenarios": rows} if rows else {})}

    def reset(self, request: dict) -> dict:
        self._counters.reset()
        self._reset_at, self._reset_mono = time.time(), time.monotonic()
        event(log, Kind.COUNTERS_RESET, "counters reset by the operator (%s)",
              operator(request.get("uid")), user=operator(request.get("uid")))
        return {"ok": True}

    def summary(self) -> str:
        c = self._counters
        return (f"transparent mode: line {'up' if self._line.up else 'down'}, "
                f"{c.frames_stored} frames stored, {c.frames_sent} sent")

    def close(self, request: dict) -> dict:
        """A client of the table's server on mdbport (not the raw port's)."""
        return self.close_table_client(self._server, request)
