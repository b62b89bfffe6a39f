"""`mbgw scan --line NAME` and `mbgw probe --line NAME`: the running daemon's line asked
through the control socket (mbgw.routing.survey answers), one survey read a call, each in
the line's own turn between the clients' transactions, at the line's settings."""
from mbgw.cli.diag import ask
from mbgw.cli.options import Failure
from mbgw.config.model import LineFormat, SerialConfig
from mbgw.line.survey import Answer

# the daemon may hold a read back behind the clients' transactions (routing.survey)
TURN_WAIT_S = 130.0


class DaemonBus:
    """The line NAME of the daemon of --control/-i, asked as mbgw.line.survey.Bus is."""

    def __init__(self, control: str | None, instance: str | None, line: str) -> None:
        self._control = control
        self._instance = instance
        self.line = line

    def settings(self) -> SerialConfig:
        """The line's device, baud rate and format (exit 1: no such line in slave mode)."""
        reply = ask(self._control, self._instance, {"command": "survey-line", "line": self.line})
        return SerialConfig(reply["device"], reply["baudrate"], LineFormat.parse(reply["format"]))

    def ask(self, unit: int, pdu: bytes, timeout_ms: int) -> Answer | None:
        reply = ask(self._control, self._instance,
                    {"command": "survey-read", "line": self.line, "unit": unit,
                     "pdu": pdu.hex(), "timeout_ms": timeout_ms},
                    timeout_ms / 1000 + TURN_WAIT_S)
        if reply["pdu"] is None:
            return None
        return Answer(bytes.fromhex(reply["pdu"]), reply["response_ns"])

    def tune(self, cfg: SerialConfig) -> None:
        raise Failure(f"line {self.line}: the daemon does not change a running line's "
                      f"settings")
