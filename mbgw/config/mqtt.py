"""Northbound MQTT ([mqtt]): the broker, the profile (Sparkplug B 3.0 or plain JSON), the
names the gateway publishes under, and who its writes are (the firewall role)."""
import re
from dataclasses import dataclass
from urllib.parse import urlsplit

from mbgw.errors import ConfigError

PROFILES = ("sparkplug", "json")
DEFAULT_PROFILE = "sparkplug"
DEFAULT_GROUP = "mbgw"
SCHEMES = {"mqtt": 1883, "mqtts": 8883}       # the IANA ports of MQTT and MQTT over TLS
# Sparkplug B 3.0 §4.1.1: group, edge node and device ids are UTF-8 strings without the
# topic's separators or wildcards; kept to what a file name and a JSON topic also take
ID_PATTERN = re.compile(r"[A-Za-z0-9_.-]{1,64}")
STALE_AFTER_RANGE = (0, 3_600_000)            # ms; 0: off (each scenario's own, if any)


@dataclass(frozen=True)
class MqttConfig:
    broker: str | None = None          # mqtt://HOST[:PORT] or mqtts://...; None: off
    profile: str = DEFAULT_PROFILE
    group: str = DEFAULT_GROUP         # Sparkplug group id; JSON: the topics' first level
    node: str | None = None            # edge node id; None: the host's (northbound.names)
    role: str | None = None            # the firewall role of writes; None: every write refused
    primary_host: str | None = None    # Sparkplug primary host application id
    cert: str | None = None            # the gateway's own client certificate (PEM) ...
    key: str | None = None             # ... its private key ...
    ca: str | None = None              # ... and the CA the broker's certificate chains to
    stale_after_ms: int = 0            # a scenario's data older than this is stale

    def __post_init__(self) -> None:
        if self.broker is not None:
            try:
                broker_address(self.broker)
            except ConfigError as err:
                raise ConfigError(f"mqtt.broker: {err}") from None
        if self.profile not in PROFILES:
            raise ConfigError(f"mqtt.profile: {self.profile!r}: expected "
                              f"{' or '.join(PROFILES)}")
        for key, value in (("group", self.group), ("node", self.node),
                           ("primary-host", self.primary_host)):
            if value is not None and not ID_PATTERN.fullmatch(value):
                raise ConfigError(f"mqtt.{key}: {value!r}: expected 1 to 64 letters, digits, "
                                  f". - or _ (no / + #)")
        if (self.cert is None) != (self.key is None):
            raise ConfigError("mqtt.cert: goes with mqtt.key: a client "
                              "certificate needs its private key")
        low, high = STALE_AFTER_RANGE
        if not low <= self.stale_after_ms <= high:
            raise ConfigError(f"mqtt.stale-after: {self.stale_after_ms}: out of range "
                              f"{low}..{high}")

    @property
    def enabled(self) -> bool:
        return self.broker is not None

    @property
    def tls(self) -> bool:
        return self.broker is not None and broker_address(self.broker)[0] == "mqtts"


def broker_address(url: str) -> tuple[str, str, int]:
    """(scheme, host, port) of `mqtt://HOST[:PORT]` or `mqtts://HOST[:PORT]`."""
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError:
        port = -1
    if parts.scheme not in SCHEMES or not parts.hostname or port == -1 \
            or parts.path not in ("", "/") or parts.query or parts.username:
        raise ConfigError(f"{url!r}: expected mqtt://HOST[:PORT] or "
                          f"mqtts://HOST[:PORT]")
    return parts.scheme, parts.hostname, port or SCHEMES[parts.scheme]
