"""The compiled firewall: Firewall.guard() at connect time, Guard.allows() per request,
Firewall.refused() for a request the guard refused (counted, logged rate-limited)."""
import logging
import struct

from mbgw.audit import Kind, event
from mbgw.config.firewall import FirewallConfig, Rule
from mbgw.net.ratelimit import RateLimitedLog
from mbgw.protocol import pdu

log = logging.getLogger("mbgw.firewall")

DEFAULT_LABEL = "default"          # the refusals of [firewall] default = "deny"
NO_ROLE_LABEL = "no-role"          # a TLS client whose certificate has no role
ILLEGAL_FUNCTION = 0x01            # MODBUS/TCP Security: an unauthorized request gets 0x01
# read-only is an allow-list of reads: every other code (writes, unknown and user-defined
# ones, which are often vendor writes or firmware transfers) is refused under it
READ_FUNCTIONS = frozenset({0x01, 0x02, 0x03, 0x04, 0x07, 0x08, 0x0B, 0x0C, 0x11, 0x14,
                            0x18, 0x2B})
_DIAGNOSTICS = 0x08                # FC 8: only the sub-functions that read
READ_DIAGNOSTICS = frozenset({0x00, *range(0x0B, 0x13)})  # 0 echo, 11-18 the counters
_MEI = 0x2B                        # FC 43: only 14, Read Device Identification
READ_MEI = frozenset({0x0E})
_ADDRESS_COUNT = struct.Struct(">HH")
_ADDRESS = struct.Struct(">H")
_SUBCODE = struct.Struct(">H")
# the functions whose PDU carries an address and a count; those that carry an address alone
_SPANS = frozenset({0x01, 0x02, 0x03, 0x04, 0x0F, 0x10})
_SINGLE = frozenset({0x05, 0x06, 0x16, 0x18})
_READ_WRITE = 0x17
# the file record functions address files, not registers: a rule with registers refuses
# them unless its functions name them
FILE_FUNCTIONS = (0x14, 0x15)
# a function's flag: refused, allowed, allowed for some sub-functions (FC 8, FC 43)
_REFUSED, _ALLOWED, _SOME = 0, 1, 2


class Guard:
    """What one client may do: the rule that selected it, compiled (256 flags by unit and by
    function; the address ranges, or None for all)."""
    __slots__ = ("rule", "label", "units", "functions", "ranges")

    def __init__(self, rule: Rule | None, label: str = DEFAULT_LABEL) -> None:
        """rule None: nothing allowed ([firewall] default = "deny", or label NO_ROLE_LABEL:
        a TLS client without a role)."""
        self.rule = rule
        self.label = label if rule is None else str(rule.index)
        units = _flags(rule.units if rule else (), 256)
        functions = _flags(rule.functions if rule else (), 256)
        if rule is not None and rule.read_only:
            units[pdu.BROADCAST] = 0              # a broadcast writes, or asks nothing
            for function in range(256):
                if function not in READ_FUNCTIONS:
                    functions[function] = _REFUSED
            for function in (_DIAGNOSTICS, _MEI):
                if functions[function]:
                    functions[function] = _SOME
        if rule is not None and rule.registers is not None:
            for function in FILE_FUNCTIONS:
                if rule.functions is None or function not in rule.functions:
                    functions[function] = _REFUSED
        self.units = bytes(units)
        self.functions = bytes(functions)
        self.ranges = rule.registers if rule else None

    def allows(self, unit: int, request) -> bool:
        """request: the PDU (function code first)."""
        function = request[0]
        flag = self.functions[function]
        if not (self.units[unit] and flag):
            return False
        if flag == _SOME and not _reads(function, request):
            return False
        ranges = self.ranges
        return ranges is None or _within(ranges, function, request)


def _reads(function: int, request) -> bool:
    """Whether an FC 8 or FC 43 request only reads: its sub-function (MEI type) is one that
    does; a PDU too short to say is refused."""
    try:
        if function == _DIAGNOSTICS:
            return _SUBCODE.unpack_from(request, 1)[0] in READ_DIAGNOSTICS
        return request[1] in READ_MEI
    except (struct.error, IndexError):
        return False


def _flags(numbers, size: int) -> bytearray:
    if numbers is None:
        return bytearray(bytes((_ALLOWED,)) * size)
    flags = bytearray(size)
    for number in numbers:
        flags[number] = _ALLOWED
    return flags


def _within(ranges, function: int, request) -> bool:
    """Whether the addresses the request touches lie in one of ranges each; a function that
    carries none passes, a PDU too short to hold them does not."""
    try:
        if function in _SPANS:
            return _span_within(ranges, *_ADDRESS_COUNT.unpack_from(request, 1))
        if function in _SINGLE:
            return _span_within(ranges, _ADDRESS.unpack_from(request, 1)[0], 1)
        if function == _READ_WRITE:
            read, read_count, write, write_count = struct.unpack_from(">HHHH", request, 1)
            return _span_within(ranges, read, read_count) and \
                _span_within(ranges, write, write_count)
    except struct.error:
        return False
    return True


def _span_within(ranges, first: int, count: int) -> bool:
    last = first + max(count, 1) - 1
    for low, high in ranges:
        if low <= first and last <= high:
            return True
    return False


_UNRULED = {DEFAULT_LABEL: "no rule (default deny)",
            NO_ROLE_LABEL: "its certificate has no role (tls.require-role)"}


class Firewall:
    """The rules of one configuration, and their refusal counts."""

    def __init__(self, cfg: FirewallConfig | None, require_role: bool = False) -> None:
        """require_role: a TLS client whose certificate has no role may do nothing ([tls]
        require-role)."""
        self.cfg = cfg or FirewallConfig()
        self.require_role = require_role
        self.refused_by = self._zero()  # by rule index, DEFAULT_LABEL or NO_ROLE_LABEL
        self._refusals = RateLimitedLog()      # logged by client (peer)

    @property
    def enabled(self) -> bool:
        return self.cfg.enabled

    @property
    def configured(self) -> bool:
        """Whether the file has rules, denies by default, or TLS clients need a role (the
        status shows it then)."""
        return bool(self.cfg.rules) or self.cfg.default != "allow" or self.require_role

    def renewed(self, cfg: FirewallConfig | None, require_role: bool = False) -> "Firewall":
        """For a reload: this one (counts kept) when the rules are the same, else a new one."""
        cfg = cfg or FirewallConfig()
        if (cfg, require_role) == (self.cfg, self.require_role):
            return self
        firewall = Firewall(cfg, require_role)
        log.info("firewall: %s", firewall.summary())
        return firewall

    def summary(self) -> str:
        rules = len(self.cfg.rules)
        return f"{rules} rule{'s' if rules != 1 else ''}, default {self.cfg.default}"

    def guard(self, host: str, role: str | None, listener: str) -> Guard | None:
        """The guard of a client (its address, its certificate's role, its listener), or None
        when it may do anything (no check per request)."""
        if role is None and listener == "tls" and self.require_role:
            return Guard(None, NO_ROLE_LABEL)
        for rule in self.cfg.rules:
            if rule.selects(host, role, listener):
                return None if rule.grants_all else Guard(rule)
        return None if self.cfg.default == "allow" else Guard(None)

    def refused(self, guard: Guard, peer: str, role: str | None, unit: int,
                request) -> bytes:
        """Count and log a request guard refused; its exception reply (0x01)."""
        label = guard.label
        self.refused_by[label] += 1
        left_out = self._refusals.due(peer)
        if left_out is not None:
            rule = guard.rule.describe() if guard.rule else _UNRULED[guard.label]
            more = f"; {left_out} more refused since the last report" if left_out else ""
            event(log, Kind.FIREWALL_REFUSED, "firewall: refused client %s (role %s) unit %d "
                  "function %d: %s%s (logged at most once a minute per client)", peer,
                  role or "none", unit, request[0], rule, more, client=peer, role=role,
                  unit=unit, function=request[0], rule=label, reason=rule)
        return pdu.exception_pdu(request[0], ILLEGAL_FUNCTION)

    def report(self, clients=()) -> dict:
        """The status's firewall part; clients: (peer, role, refused) of those connected."""
        return {"default": self.cfg.default,
                "clients": [{"peer": peer, "role": role, "refused": refused}
                            for peer, role, refused in clients],
                "rules": [{"rule": r.index, "selects": r.describe(),
                           "refused": self.refused_by.get(str(r.index), 0)}
                          for r in self.cfg.rules],
                "refused_default": self.refused_by.get(DEFAULT_LABEL, 0),
                "require_role": self.require_role,
                "refused_no_role": self.refused_by.get(NO_ROLE_LABEL, 0),
                "refused": sum(self.refused_by.values())}

    def reset_counts(self) -> None:
        self.refused_by = self._zero()

    def _zero(self) -> dict[str, int]:
        """Every label there from the start: the line thread never grows the dict that
        another thread reads."""
        return dict.fromkeys([*(str(r.index) for r in self.cfg.rules), DEFAULT_LABEL,
                              NO_ROLE_LABEL], 0)
