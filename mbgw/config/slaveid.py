"""Master mode's slaveid table: which remote Modbus TCP server, and which unit id there, each
serial address the master polls stands for.

A line is the ACKSYS `set net slaveid fs ls fr m ip` (Modbus TCP user guide, "Syntax in
MASTER mode"): serial addresses fs..ls go to ip; the unit id sent is fr + (address - fs), or
0xFF when fr is 0; with m = 1 the last byte of ip grows with (address - fs) too.  A line
whose fs falls inside a range already defined replaces the oldest such range; fs = 0 clears
the table; at most 8 ranges.  A range that would overlap another is refused: the guide
does not say which would serve the addresses they share.  An optional 6th word `tls` (ours,
not ACKSYS's) has the range's servers reached over Modbus/TCP Security.
"""
import ipaddress
from dataclasses import dataclass
from typing import Iterable

from mbgw.errors import ConfigError
from mbgw.protocol import pdu

MAX_RANGES = 8
NO_UNIT_ID = 0xFF       # TCP guide 4.4.1.2: the unit id "useless" to a device on TCP itself
MAX_UNIT_ID = 0xFF


def parse_fingerprint(label: str, text: str) -> bytes:
    """A server certificate's SHA-256 fingerprint, pinned: 64 hex digits, colons between the
    bytes allowed (as `openssl x509 -noout -fingerprint -sha256` prints it), "sha256:" or
    "sha256 Fingerprint=" before them too.  Raises ConfigError naming label."""
    digits = text.strip()
    for prefix in ("sha256 fingerprint=", "sha256:", "sha256="):
        if digits.lower().startswith(prefix):
            digits = digits[len(prefix):]
    digits = digits.replace(":", "")
    try:
        value = bytes.fromhex(digits)
    except ValueError:
        value = b""
    if len(value) != 32:
        raise ConfigError(f"{label}: fingerprint {text!r}: expected the certificate's SHA-256 "
                          f"fingerprint, 32 bytes in hex (openssl x509 -noout -fingerprint "
                          f"-sha256 prints it)")
    return value


@dataclass(frozen=True)
class SlaveRange:
    first: int                  # fs: first serial address
    last: int                   # ls: last serial address
    remote_first: int           # fr: unit id of `first`; 0: every unit id is 0xFF
    variable_ip: bool           # m = 1: the IP's last byte follows the address
    ip: ipaddress.IPv4Address
    tls: bool = False           # `tls`: its servers are reached over TLS
    fingerprint: bytes | None = None   # pinned SHA-256 of the servers' certificate (tls)

    @classmethod
    def parse(cls, text: str) -> "SlaveRange | None":
        """'fs ls fr m ip [tls [fingerprint]]' -> a range; None for a line that clears the
        table (fs = 0)."""
        words = text.split()
        try:
            numbers = [int(w) for w in words[:4]]
        except ValueError:
            numbers = []
        if numbers[:1] == [0]:
            return None
        tls = len(words) in (6, 7) and words[5].lower() == "tls"
        if len(words) not in ((5, 6, 7) if tls else (5,)) or len(numbers) != 4:
            raise ConfigError(f"slaveid {text!r}: expected 'FS LS FR M IP', 'FS LS FR M IP "
                              f"tls' or 'FS LS FR M IP tls FINGERPRINT', e.g. "
                              f"'1 8 1 0 192.168.0.30'")
        fingerprint = parse_fingerprint(f"slaveid {text!r}", words[6]) \
            if len(words) == 7 else None
        first, last, remote_first, mode = numbers
        try:
            ip = ipaddress.IPv4Address(words[4])
        except ValueError:
            raise ConfigError(f"slaveid {text!r}: {words[4]!r} is not an IPv4 address") from None
        return cls.checked(text, first, last, remote_first, mode, ip, tls, fingerprint)

    @classmethod
    def checked(cls, text: str, first: int, last: int, remote_first: int, mode: int,
                ip: ipaddress.IPv4Address, tls: bool = False,
                fingerprint: bytes | None = None) -> "SlaveRange":
        def bad(reason: str) -> ConfigError:
            return ConfigError(f"slaveid {text!r}: {reason}")

        if not 1 <= first <= pdu.MAX_SERIAL_ADDRESS:
            raise bad(f"first address {first} outside 1..{pdu.MAX_SERIAL_ADDRESS} (0 clears)")
        if not first <= last <= pdu.MAX_SERIAL_ADDRESS:
            raise bad(f"last address {last} outside {first}..{pdu.MAX_SERIAL_ADDRESS}")
        span = last - first
        if not 0 <= remote_first <= MAX_UNIT_ID or (
                remote_first and remote_first + span > MAX_UNIT_ID):
            raise bad(f"remote unit ids {remote_first}..{remote_first + span} outside 1..255")
        if mode not in (0, 1):
            raise bad(f"mode {mode}: 0 (one IP) or 1 (the IP's last byte follows the address)")
        if ip.is_unspecified or ip.is_multicast:
            raise bad(f"{ip} cannot be a server's address")
        if mode and (int(ip) & 0xFF) + span > 0xFF:
            raise bad(f"{ip} + {span} runs past the last byte of the address")
        return cls(first, last, remote_first, bool(mode), ip, tls, fingerprint)

    def overlaps(self, other: "SlaveRange") -> bool:
        return self.first <= other.last and other.first <= self.last

    def line(self) -> str:
        """The range as parse() reads it: 'fs ls fr m ip [tls [fingerprint]]'."""
        pin = f" {self.fingerprint.hex(':').upper()}" if self.fingerprint else ""
        return f"{self.first} {self.last} {self.remote_first} {int(self.variable_ip)} " \
               f"{self.ip}{' tls' if self.tls else ''}{pin}"

    def route(self, address: int) -> tuple[str, int]:
        """(server IP, unit id) for a serial address of this range."""
        offset = address - self.first
        unit = self.remote_first + offset if self.remote_first else NO_UNIT_ID
        return str(self.ip + offset if self.variable_ip else self.ip), unit

    def __str__(self) -> str:
        last_ip, last_unit = self.route(self.last)
        first_ip, first_unit = self.route(self.first)
        ips = f"{first_ip}..{last_ip}" if first_ip != last_ip else first_ip
        units = f"{first_unit}..{last_unit}" if first_unit != last_unit else f"{first_unit}"
        return f"{self.first}..{self.last} -> {ips} unit {units}{' (TLS)' if self.tls else ''}"


class SlaveIdTable:
    """The ranges in the order they were defined, and a lookup for each serial address."""

    def __init__(self, entries: Iterable[SlaveRange | None] = ()) -> None:
        ranges: list[SlaveRange] = []
        for entry in entries:
            if entry is None:
                ranges.clear()
                continue
            holding = [r for r in ranges if r.first <= entry.first <= r.last]
            if holding:
                ranges.remove(holding[0])
            elif len(ranges) == MAX_RANGES:
                raise ConfigError(f"slaveid: at most {MAX_RANGES} ranges (FS=0 clears the table)")
            for other in ranges:
                if other.overlaps(entry):
                    raise ConfigError(f"slaveid: addresses {entry.first}..{entry.last} overlap "
                                      f"the range {other.first}..{other.last}")
            ranges.append(entry)
        self.ranges = tuple(ranges)
        routes: list[tuple[str, int] | None] = [None] * 256
        for r in self.ranges:
            for address in range(r.first, r.last + 1):
                routes[address] = r.route(address)
        self._routes = tuple(routes)
        self.destinations = tuple(dict.fromkeys(route[0] for route in routes if route))
        self.tls_hosts = self._tls_hosts()
        # the servers whose certificate is pinned (instead of matching their address)
        self.pins = {r.route(a)[0]: r.fingerprint for r in self.ranges if r.fingerprint
                     for a in range(r.first, r.last + 1)}

    def _tls_hosts(self) -> frozenset[str]:
        """The servers reached over TLS; one server is reached one way only."""
        tls: dict[str, SlaveRange] = {}
        plain: dict[str, SlaveRange] = {}
        for r in self.ranges:
            for address in range(r.first, r.last + 1):
                (tls if r.tls else plain)[r.route(address)[0]] = r
        for host in tls.keys() & plain.keys():
            raise ConfigError(f"slaveid: server {host} is reached over TLS by the range "
                              f"{tls[host].first}..{tls[host].last} and without by the range "
                              f"{plain[host].first}..{plain[host].last}")
        return frozenset(tls)

    @classmethod
    def parse(cls, lines: Iterable[str]) -> "SlaveIdTable":
        return cls(SlaveRange.parse(line) for line in lines)

    def route(self, address: int) -> tuple[str, int] | None:
        """(server IP, unit id) for a serial address; None when no range holds it."""
        return self._routes[address]

    def __eq__(self, other) -> bool:
        return isinstance(other, SlaveIdTable) and self.ranges == other.ranges

    def __hash__(self) -> int:
        return hash(self.ranges)

    def __str__(self) -> str:
        return ", ".join(str(r) for r in self.ranges) or "empty"
