"""Northbound MQTT's figures, for the status, /metrics and the console."""
from dataclasses import dataclass, field


@dataclass
class NorthboundCounters:
    connected: bool = False
    broker: str = ""
    node: str = ""
    profile: str = ""
    sent: int = 0                  # messages published
    dropped: int = 0               # values a slow broker could not take (a newer one followed)
    refused: int = 0               # writes refused: no role, the firewall, a bad value
    writes: int = 0                # writes sent to a device
    connects: int = 0              # sessions opened
    # each line's state as the broker last got it (Lines/NAME/State)
    lines: dict[str, str] = field(default_factory=dict)

    def snapshot(self) -> dict:
        return {"connected": self.connected, "broker": self.broker, "node": self.node,
                "profile": self.profile, "messages_sent": self.sent,
                "messages_dropped": self.dropped, "commands_refused": self.refused,
                "writes": self.writes, "connects": self.connects,
                "lines": dict(self.lines)}
