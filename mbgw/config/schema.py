"""The keys of the configuration file: the long options of the mode commands (`mbgw slave`,
`mbgw master`), walked at run time so that an option added to a command is a key at once, in
the groups of the ACKSYS guide ([serial], [net], [general]) and [table] (the exchange table),
with their built-in defaults."""
import dataclasses
import difflib
from pathlib import Path

import click

DEFAULT_PATH = Path("/etc/mbgw/mbgw.toml")
CONFIG_DIR = DEFAULT_PATH.parent           # the instance mbgw@NAME reads CONFIG_DIR/NAME.toml
MODES = ("slave", "master", "transparent")  # "set serial mode slave|master|transparent"
MODE_KEY = "mode"                          # in [serial]; selects the command `mbgw run` starts
PROTOCOL_KEY = "protocol"                  # "set serial mode rtu|ascii" sets it
PROTOCOL_WORDS = ("rtu", "ascii")
GROUPS = ("serial", "net", "general", "table", "tls", "transparent", "web", "mqtt")
# [serial]: the options of class SerialOption (both modes' line settings) and the slave mode's
# line behaviour below; [net]: the guide's "set net ..." commands and
# our network options; [general]: the rest (logging, control socket, metrics, ...); [table]:
# the options of class TableOption, each under its own key (--table-units is table.units).
LINE_KEYS = frozenset({"retries", "turnaround", "late-window", "cache"})
NET_KEYS = frozenset({"slaveid", "authip", "mdbport", "tcpto", "exception", "bind",
                      "max-connections", "max-connections-per-ip", "request-timeout",
                      "udp-port", "rtu-port"})
# The guide's keys that mbgw refuses on purpose, and why (not "unknown key").
NOT_SUPPORTED = {
    ("net", "metric"): "not supported: the guide's gateway hop count is a route metric of the "
                       "host (ip route ... metric N), which a daemon without CAP_NET_ADMIN "
                       "cannot set; set it in the host's network configuration",
}
MODE_TABLES = ("authip", "slaveid")        # cleared when the mode changes (the guide says so)
AUTHIP_ENTRIES = 8                         # "n: table entry index, from 1 to 8"
NO_ADDRESS = "0.0.0.0"                     # "IP address 0.0.0.0 clears the entry"
FACTORY_MODE = "slave"
FACTORY_DEVICE = "/dev/ttyUSB0"
OWN_OPTIONS = frozenset({"config"})        # the option naming the file is not a key
# The values of the keys that take one of a set click does not list (a click.Choice's own are
# read from it): the web console offers them as choices.
FORMAT_WORDS = tuple(f"{d}{p}{s}" for d in "87" for p in "neoms" for s in "12")
INTERFACE_WORDS = ("rs232", "rs485", "rs485 echo", "rs422", "rs422 slave")
FLAG_WORDS = ("on", "off")
CHOICES = {MODE_KEY: MODES, "format": FORMAT_WORDS, "interface": INTERFACE_WORDS}
UNITS = {"baudrate": "bit/s"}
METAVAR_UNITS = {"MS": "ms", "S": "s", "BYTES": "bytes"}
MODE_HELP = ("slave: Modbus slaves on the serial line; master: a Modbus master on it; "
             "transparent: frames passed as they are. Changing it needs a restart.")


@dataclasses.dataclass
class Key:
    name: str                  # the ACKSYS spelling: the option's long flag without "--"
    group: str
    params: dict               # mode -> its click.Option (one per mode command that has it)
    file_name: str = ""        # as written under [group]: the name, unless it is another
                               # group's already ([tls] port is --tls-port)

    def __post_init__(self) -> None:
        self.file_name = self.file_name or self.name

    def mode_for(self, mode: str) -> str:
        """The mode whose option checks this key: the file's mode when it has the key."""
        return mode if mode in self.params else next(iter(self.params))

    @property
    def label(self) -> str:
        return f"{self.group}.{self.file_name}"


class Schema:
    """The keys of the mode commands of `root` (a click group), in [serial], [net], [general],
    [table] order, each group in the commands' option order."""

    def __init__(self, root: click.Group) -> None:
        self.root = root
        self.commands = {m: root.commands[m] for m in MODES if m in root.commands}
        if not self.commands:
            raise RuntimeError(f"{root.name} has no mode command ({', '.join(MODES)})")
        self.modes = tuple(self.commands)
        found: dict[str, Key] = {}
        for mode, command in self.commands.items():
            for param in command.params:
                name = option_key(param)
                if name is not None:
                    group = key_group(name, param)
                    found.setdefault(name, Key(name, group, {}, file_key(param))) \
                        .params[mode] = param
                    if found[name].group != group:
                        raise RuntimeError(f"key {name} is in [{found[name].group}] and "
                                           f"[{group}]")
        self.keys = {k.name: k for g in GROUPS for k in found.values() if k.group == g}
        self._in_file = {(k.group, k.file_name): k for k in self.keys.values()}

    @property
    def default_mode(self) -> str:
        return FACTORY_MODE if FACTORY_MODE in self.modes else self.modes[0]

    def group_keys(self, group: str) -> list[str]:
        """The keys of a group as the file and `config show` list them: the secrets (password
        hashes) never."""
        names = [k.name for k in self.keys.values() if k.group == group
                 and not any(is_secret(p) for p in k.params.values())]
        return [MODE_KEY, *names] if group == "serial" else names

    def find(self, group: str, file_name: str) -> Key | None:
        """The key written file_name under [group]."""
        return self._in_file.get((group, file_name))

    def place(self, name: str) -> tuple[str, str]:
        """(group, name in the file) of a key."""
        if name == MODE_KEY:
            return "serial", MODE_KEY
        key = self.keys[name]
        return key.group, key.file_name

    def file_name(self, name: str) -> str:
        return self.place(name)[1]

    def label(self, name: str) -> str:
        return ".".join(self.place(name))

    def hint(self, name: str) -> str:
        """'; did you mean net.authip?' for a misspelt key, else ''."""
        labels = {f"{MODE_KEY}": f"serial.{MODE_KEY}"}
        for key in reversed(self.keys.values()):
            labels[key.file_name] = key.label
        match = difflib.get_close_matches(name.lower(), list(labels), n=1, cutoff=0.6)
        return f"; did you mean {labels[match[0]]}?" if match else ""

    def key_of_param(self, param: click.Parameter) -> Key | None:
        name = option_key(param)
        return self.keys.get(name) if name else None


@dataclasses.dataclass(frozen=True)
class KeyHelp:
    """What an operator needs to set a key: its help, its unit ("" when none), its choices
    (() when it takes any value) and the modes it applies to."""
    help: str
    unit: str
    choices: tuple[str, ...]
    modes: tuple[str, ...]


def key_help(schema: Schema, name: str) -> KeyHelp:
    if name == MODE_KEY:
        return KeyHelp(MODE_HELP, "", MODES, schema.modes)
    key = schema.keys[name]
    param = next(iter(key.params.values()))
    metavar = param.metavar or ""
    if name in CHOICES:
        choices: tuple[str, ...] = CHOICES[name]
    elif isinstance(param.type, click.Choice):
        choices = tuple(map(str, param.type.choices))
    elif isinstance(param, click.Option) and param.is_flag:
        choices = FLAG_WORDS
    else:
        choices = ()
    return KeyHelp(param.help or "", UNITS.get(name, METAVAR_UNITS.get(metavar, "")), choices,
                   tuple(m for m in schema.modes if m in key.params))


def key_group(name: str, param: click.Parameter) -> str:
    if isinstance(param, TableOption):
        return param.group
    if isinstance(param, TransparentOption):
        return "transparent"
    if name in NET_KEYS:
        return "net"
    return "serial" if name in LINE_KEYS or isinstance(param, SerialOption) else "general"


def file_key(param: click.Parameter) -> str:
    """The name a grouped option's key has in the file, when its own name would be another
    group's key's ("" when it is the same)."""
    return getattr(param, "file_key", None) or ""


def option_key(param: click.Parameter) -> str | None:
    """The configuration key of a command option: its long flag without the dashes (a
    TableOption's own key)."""
    if not isinstance(param, click.Option) or not param.expose_value \
            or (param.hidden and not is_secret(param)) or param.name in OWN_OPTIONS:
        return None
    if isinstance(param, (TableOption, TransparentOption)):
        return param.key
    longs = [o for o in param.opts if o.startswith("--")]
    return longs[0][2:] if longs else None


class SerialOption(click.Option):
    """An option of the serial line (both modes'): its key is in [serial], so a new serial
    option is there at once."""


class TableOption(click.Option):
    """An option of the exchange table (--table, --table-units, ...): its key is `key` in
    [table] (table.enabled, table.units, ...)."""

    group = "table"

    def __init__(self, *args, key: str, file_key: str | None = None, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.key = key
        self.file_key = file_key


class TlsOption(TableOption):
    """An option of Modbus/TCP Security (--tls-cert, ...): its key is `key` in [tls]."""
    group = "tls"


class WebOption(TableOption):
    """An option of the web console (--web, --web-cert, ...): its key is `key` in [web].
    secret: a password hash, a key of the file only (a hidden option), never shown."""
    group = "web"

    def __init__(self, *args, secret: bool = False, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.secret = secret


class MqttOption(TableOption):
    """An option of northbound MQTT (--mqtt-broker, ...): its key is `key` in [mqtt]."""
    group = "mqtt"


def is_secret(param: click.Parameter | None) -> bool:
    """A key `mbgw config show` and the web console never show (the password hashes)."""
    return bool(getattr(param, "secret", False))


class TransparentOption(click.Option):
    """An option of transparent mode (--eof, --rx-address, ...): its key is `key` in
    [transparent]."""

    def __init__(self, *args, key: str, file_key: str | None = None, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.key = key
        self.file_key = file_key


def is_unset(value) -> bool:
    """click 8.1 says None where click 8.2+ says Sentinel.UNSET."""
    return value is None or (type(value).__name__ == "Sentinel"
                             and getattr(value, "name", "") == "UNSET")


def default_value(schema: Schema, name: str, mode: str):
    """The built-in default of a key in a mode, as it would be written in the file; None if it
    has none."""
    if name == MODE_KEY:
        return schema.default_mode
    key = schema.keys[name]
    mode = key.mode_for(mode)
    param = key.params[mode]
    value = param.get_default(click.Context(schema.commands[mode], info_name=mode))
    if is_unset(value):
        return [] if param.multiple else None
    if param.multiple or param.nargs != 1:
        return list(value)
    return value

