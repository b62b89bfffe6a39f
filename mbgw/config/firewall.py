"""The Modbus firewall's settings: `[[rule]]` tables and `[firewall] default` in the
configuration file (not options of the mode commands: a rule is a table of its own).

A rule's `role`, `client` and `listener` select the clients it is for (all three are known
when a client connects); `units`, `functions`, `registers` and `read-only` say what it lets
them do.  The first rule that selects a client decides everything that client may do; a
client no rule selects is allowed everything (`default = "allow"`) or nothing ("deny")."""
import dataclasses
import ipaddress

from mbgw.config.number_list import number_list_text, parse_number_list
from mbgw.config.tables import array_of_tables, check_keys, parse_each, typed
from mbgw.errors import ConfigError

GROUP = "firewall"                 # [firewall]
RULE_TABLE = "rule"                # [[rule]]
DEFAULT_KEY = "default"
POLICIES = ("allow", "deny")
DEFAULT_POLICY = "allow"           # no rules: every request goes through, as before
# [net] mdbport, tls port, udp-port, rtu-port; mqtt: writes from the broker ([mqtt] role)
LISTENERS = ("tls", "plain", "udp", "rtu", "mqtt")
GROUP_KEYS = (DEFAULT_KEY,)
RULE_KEYS = ("role", "client", "listener", "units", "functions", "registers", "read-only")
UNIT_RANGE = (0, 255)
FUNCTION_RANGE = (1, 127)          # 128.. are exception replies, never requests
REGISTER_RANGE = (0, 65535)
PARAM = "firewall"                 # the mode commands' hidden parameter the file fills in

Network = ipaddress.IPv4Network | ipaddress.IPv6Network


@dataclasses.dataclass(frozen=True)
class Rule:
    """One [[rule]]; None in a selector: any; None in a grant: all."""
    index: int                                 # 1-based, its place in the file
    role: str | None = None
    clients: tuple[Network, ...] | None = None
    listener: str | None = None
    units: tuple[int, ...] | None = None
    functions: tuple[int, ...] | None = None
    registers: tuple[tuple[int, int], ...] | None = None   # (first, last) address ranges
    read_only: bool = False

    def selects(self, host: str, role: str | None, listener: str) -> bool:
        if self.role is not None and role != self.role:
            return False
        if self.listener is not None and listener != self.listener:
            return False
        if self.clients is not None:
            address = ipaddress.ip_address(host.split("%", 1)[0])
            if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped:
                address = address.ipv4_mapped
            return any(address in network for network in self.clients)
        return True

    @property
    def grants_all(self) -> bool:
        return self.units is None and self.functions is None and self.registers is None \
            and not self.read_only

    def describe(self) -> str:
        """'rule 2 (role operator, client 10.0.0.0/8)' for logs."""
        parts = [f"role {self.role}"] if self.role is not None else []
        if self.clients is not None:
            parts.append("client " + ",".join(map(str, self.clients)))
        if self.listener is not None:
            parts.append(f"listener {self.listener}")
        return f"rule {self.index}" + (f" ({', '.join(parts)})" if parts else "")


@dataclasses.dataclass(frozen=True)
class FirewallConfig:
    rules: tuple[Rule, ...] = ()
    default: str = DEFAULT_POLICY

    @property
    def enabled(self) -> bool:
        """Whether anything can be refused."""
        return self.default != "allow" or any(not r.grants_all for r in self.rules)


def from_file(data: dict) -> tuple[FirewallConfig, list[str]]:
    """The firewall of a parsed configuration file (its [firewall] group and [[rule]] tables),
    and the problems found, each naming the key (`rule 2.functions`) and the reason."""
    problems: list[str] = []
    default = _policy(data.get(GROUP, {}), problems)
    wrong = (f"[{RULE_TABLE}]: write [[{RULE_TABLE}]] (one table per rule, in order), not "
             f"[{RULE_TABLE}]" if isinstance(data.get(RULE_TABLE), dict)
             else f"{RULE_TABLE}: expected [[{RULE_TABLE}]] tables, not a value")
    rules, rule_problems = parse_each(array_of_tables(data, RULE_TABLE, problems, wrong),
                                      parse_rule)
    return FirewallConfig(rules, default), problems + rule_problems


def _policy(group, problems: list[str]) -> str:
    if not isinstance(group, dict):
        problems.append(f"{GROUP}: expected a group [{GROUP}], not a value")
        return DEFAULT_POLICY
    for name in group:
        if name not in GROUP_KEYS:
            problems.append(f"{GROUP}.{name}: unknown key (keys: {', '.join(GROUP_KEYS)})")
    value = group.get(DEFAULT_KEY, DEFAULT_POLICY)
    if value not in POLICIES:
        problems.append(f"{GROUP}.{DEFAULT_KEY}: expected "
                        f"{' or '.join(repr(p) for p in POLICIES)}, got {value!r}")
        return DEFAULT_POLICY
    return value


def parse_rule(index: int, table: dict) -> Rule:
    """A [[rule]] table (the index-th, from 1).  Raises ConfigError naming the rule and key."""
    label = f"{RULE_TABLE} {index}"
    check_keys(label, table, RULE_KEYS)
    role = table.get("role")
    if role is not None and (not isinstance(role, str) or not role):
        raise ConfigError(f"{label}.role: expected the role's name, got {role!r}")
    listener = table.get("listener")
    if listener is not None and listener not in LISTENERS:
        raise ConfigError(f"{label}.listener: expected "
                          f"{' or '.join(repr(n) for n in LISTENERS)}, got {listener!r}")
    read_only = typed(label, table, "read-only", bool, "true or false", False)
    return Rule(index, role, _clients(label, table.get("client")), listener,
                _numbers(label, "units", table.get("units"), UNIT_RANGE),
                _numbers(label, "functions", table.get("functions"), FUNCTION_RANGE),
                _ranges(label, table.get("registers")), read_only)


def _clients(label: str, value) -> tuple[Network, ...] | None:
    if value is None:
        return None
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list) or not items or not all(isinstance(i, str) for i in items):
        raise ConfigError(f"{label}.client: expected a CIDR (\"192.168.1.0/24\", "
                          f"\"fd00::/8\") or a list of them, got {value!r}")
    networks = []
    for item in items:
        try:
            networks.append(ipaddress.ip_network(item))
        except ValueError as err:
            raise ConfigError(f"{label}.client {item!r}: not a CIDR ({err})") from None
    return tuple(networks)


def _numbers(label: str, key: str, value, bounds: tuple[int, int]) -> tuple[int, ...] | None:
    """A list of integers, one integer, or the text "1-10,20"."""
    if value is None:
        return None
    low, high = bounds
    if isinstance(value, bool) or not isinstance(value, (int, str, list)):
        raise ConfigError(f"{label}.{key}: expected numbers such as \"1-10,20\" or [1, 2], "
                          f"got {value!r}")
    if isinstance(value, list):
        if not value or not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            raise ConfigError(f"{label}.{key}: expected a list of integers, got {value!r}")
        value = ",".join(map(str, value))
    return parse_number_list(f"{label}.{key}", str(value), low, high)


def _ranges(label: str, value) -> tuple[tuple[int, int], ...] | None:
    numbers = _numbers(label, "registers", value, REGISTER_RANGE)
    if numbers is None:
        return None
    ranges: list[tuple[int, int]] = []
    for part in number_list_text(numbers).split(","):
        first, _, last = part.partition("-")
        ranges.append((int(first), int(last or first)))
    return tuple(ranges)
