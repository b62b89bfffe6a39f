"""One value of the configuration file, checked by its key's option exactly as the command
line would be (its click type, then its callback), after a check of its TOML shape; and the
tables whose file form is the guide's: net.authip (entries 1..8, 0.0.0.0 for an empty one)
and master mode's net.slaveid (ranges "FS LS FR M IP", no two overlapping)."""
import click

from mbgw.config.model import table_address_conflict
from mbgw.config.schema import AUTHIP_ENTRIES, NO_ADDRESS, Key, Schema, default_value
from mbgw.config.slaveid import SlaveIdTable, SlaveRange
from mbgw.config.toml_text import dump_value, dumpable
from mbgw.errors import ConfigError, MbgwError


def _kind(param_type: click.ParamType) -> str:
    if isinstance(param_type, click.types.BoolParamType):
        return "bool"
    if isinstance(param_type, click.types.IntParamType):
        return "int"
    if isinstance(param_type, click.types.FloatParamType):
        return "float"
    if isinstance(param_type, (click.types.StringParamType, click.Choice)):
        return "str"
    return "any"


def element_kinds(param: click.Parameter) -> list[str]:
    if isinstance(param.type, click.Tuple):
        return [_kind(t) for t in param.type.types]
    return [_kind(param.type)] * max(param.nargs, 1)


_KIND_CHECKS = {
    "bool": (lambda v: isinstance(v, bool), "true or false"),
    "int": (lambda v: isinstance(v, int) and not isinstance(v, bool), "an integer"),
    "float": (lambda v: isinstance(v, (int, float)) and not isinstance(v, bool), "a number"),
    "str": (lambda v: isinstance(v, str), "a string"),
    "any": (lambda v: isinstance(v, (str, int, float, bool)), "a value"),
}


def _kind_problem(kinds: list[str], values: list) -> str | None:
    for kind, value in zip(kinds, values, strict=True):
        accepts, wanted = _KIND_CHECKS[kind]
        if not accepts(value):
            shown = dump_value(value) if dumpable(value) else repr(value)
            return f"expected {wanted}, got {shown}"
    return None


def _shape_problem(param: click.Parameter, value) -> str | None:
    """Is the TOML value the shape the option takes (scalar, list of N, list)?"""
    if getattr(param.type, "takes_table", False) and (isinstance(value, dict) or value is False):
        return None                        # its type checks the table's keys
    if isinstance(value, dict):
        return "expected a value, not a table"
    if param.multiple:
        if not isinstance(value, list):
            return "expected a list, e.g. [\"...\"]"
        if param.nargs != 1:
            return None                    # entries are "A B" strings or lists: click checks
        return next(filter(None, (_kind_problem(element_kinds(param), [v]) for v in value)),
                    None)
    if param.nargs != 1:
        if not isinstance(value, list) or len(value) != param.nargs:
            return f"expected a list of {param.nargs} values"
        return _kind_problem(element_kinds(param), value)
    if isinstance(value, list):
        return "expected a single value, not a list"
    return _kind_problem(element_kinds(param), [value])


def to_click(name: str, param: click.Parameter, value):
    """A file value as the command line would give it to click."""
    if name == "authip" and param.multiple:
        return [v for v in value if v != NO_ADDRESS]
    if param.multiple and param.nargs != 1:
        return [v.split() if isinstance(v, str) else v for v in value]
    return value


class Problem(MbgwError):
    """A value its option refuses; the message says why."""


def process(command: click.Command, param: click.Parameter, value):
    """Convert and check a value exactly as the command line would: type, then callback."""
    ctx = click.Context(command, info_name=command.name)
    try:
        return param.process_value(ctx, value)
    except click.BadParameter as err:
        raise Problem(err.message) from None
    except click.UsageError as err:
        raise Problem(err.format_message()) from None
    except (TypeError, ValueError, AttributeError):
        raise Problem(f"invalid value {value!r}") from None



def check_value(schema: Schema, key: Key, mode: str, value, label: str | None = None
                ) -> list[str]:
    """Problems with one key's value, checked by the option of the file's mode (or of the mode
    that has the key); each names it by label (default: the key's, e.g. serial.stout)."""
    mode = key.mode_for(mode)
    command, param = schema.commands[mode], key.params[mode]
    label = label or key.label
    if key.name == "authip" and param.multiple:
        return _check_authip(command, param, value, label)
    if key.name == "slaveid" and param.multiple:
        return _check_slaveid_table(command, param, value, label)
    shape = _shape_problem(param, value)
    if shape:
        return [f"{label}: {shape}"]
    if param.multiple:
        problems = []
        for index, element in enumerate(value, 1):
            try:
                process(command, param, to_click(key.name, param, [element]))
            except Problem as problem:
                problems.append(f"{label}[{index}]: {problem}")
        if problems:
            return problems
    try:
        process(command, param, to_click(key.name, param, value))
    except Problem as problem:
        return [f"{label}: {problem}"]
    return []


def _check_authip(command, param, value, label) -> list[str]:
    if not isinstance(value, list):
        return [f"{label}: expected a list of addresses, e.g. [\"192.168.1.5\"]"]
    if len(value) > AUTHIP_ENTRIES:
        return [f"{label}: {len(value)} entries, the table holds {AUTHIP_ENTRIES}"]
    problems = []
    for index, entry in enumerate(value, 1):
        if not isinstance(entry, str):
            problems.append(f"{label}[{index}]: expected an address string, got {entry!r}")
        elif entry != NO_ADDRESS:
            try:
                process(command, param, [entry])
            except Problem as problem:
                problems.append(f"{label}[{index}]: {problem}")
    return problems


def _check_slaveid_table(command, param, value, label) -> list[str]:
    """Master mode's table: each entry a range "FS LS FR M IP", no two ranges overlapping
    (in a file, a range whose FS lies in another would silently replace it)."""
    if not isinstance(value, list):
        return [f"{label}: in master mode, a list of ranges \"FS LS FR M IP\""]
    problems: list[str] = []
    ranges: list[tuple[int, SlaveRange]] = []
    for index, entry in enumerate(value, 1):
        try:
            if not isinstance(entry, str):
                raise ConfigError(f"expected a string \"FS LS FR M IP\", got {entry!r}")
            entry_range = SlaveRange.parse(entry)
            if entry_range is None:
                raise ConfigError("FS 0 clears the table: leave the list empty instead")
        except ConfigError as problem:
            problems.append(f"{label}[{index}]: {problem}")
            continue
        for other_index, other in ranges:
            if entry_range.overlaps(other):
                problems.append(f"{label}[{index}]: addresses {entry_range.first}.."
                                f"{entry_range.last} overlap {label}[{other_index}] "
                                f"({other.first}..{other.last})")
        ranges.append((index, entry_range))
    if not problems:
        try:
            process(command, param, value)
        except Problem as problem:
            problems.append(f"{label}: {problem}")
    return problems


def check_across(schema: Schema, mode: str, values: dict) -> list[str]:
    """What only keys together can get wrong, once each is right: in master mode, the
    table's serial address inside a slaveid range; a `tls` range without the client
    certificate (the files that go together are checked at start, as the server's)."""
    return _upstream_tls_problems(schema, mode, values) + \
        _table_address_problems(schema, mode, values)


def _upstream_tls_problems(schema: Schema, mode: str, values: dict) -> list[str]:
    if "client-cert" not in schema.keys:
        return []
    if values.get("client-cert") or mode != "master" or not values.get("slaveid"):
        return []
    return [f"net.slaveid: the range {r.line()!r} needs tls.client-cert, tls.client-key and "
            f"tls.server-ca" for r in SlaveIdTable.parse(values["slaveid"]).ranges if r.tls]


def _table_address_problems(schema: Schema, mode: str, values: dict) -> list[str]:
    if mode != "master" or not {"enabled", "address", "slaveid"} <= set(schema.keys):
        return []

    def value(name: str):
        return values[name] if name in values else default_value(schema, name, mode)
    if not value("enabled"):
        return []
    conflict = table_address_conflict(value("address"), SlaveIdTable.parse(value("slaveid")))
    return [f"table.address: {conflict} (net.slaveid)"] if conflict else []
