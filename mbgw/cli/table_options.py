"""The exchange table's options ([table] keys) and the TableConfig they build: --table, then
the mode's own table options, then these."""
import os

import click

from mbgw.cli.options import convert, parser, stack
from mbgw.config import model
from mbgw.config.number_list import parse_number_list
from mbgw.config.schema import TableOption
from mbgw.errors import ConfigError

# The exchange table ([table] keys): --table first, then the mode's own options, then these.
table_switch = click.option(
    "--table/--no-table", "table_enabled", cls=TableOption, key="enabled",
    default=model.TableConfig.enabled, show_default=True,
    help="Serve the exchange table: 65,536 registers of local data that Modbus TCP clients "
         "and the serial side read and write (mbgw.toml(5), [table]).  Slave mode: TCP "
         "units --table-units reach it (every unit with --no-direct); master mode: the "
         "serial address --table-address, and TCP clients on --table-port.")


def _parse_functions(value, option: str = "table-functions") -> tuple[int, ...]:
    functions = parse_number_list(option, value, 1, 255)
    others = [str(f) for f in functions if f not in model.TABLE_FUNCTIONS]
    if others:
        raise ConfigError(f"{option} {value!r}: {', '.join(others)}: the table "
                          f"answers only {', '.join(map(str, model.TABLE_FUNCTIONS))}")
    return functions


def parse_serial_functions(value) -> tuple[int, ...] | None:
    return None if value is None else _parse_functions(value, "table-serial-functions")


def _parse_persist(value):
    if value is not None and value != PERSIST_OFF:
        model.check_persist_path(str(value))
    return value


table_options = stack(
    click.option("--table-functions", cls=TableOption, key="functions",
                 default=",".join(map(str, model.TABLE_FUNCTIONS)), show_default=True,
                 callback=parser(_parse_functions), metavar="LIST",
                 help="Function codes the table answers, of %s (e.g. 3,4,6,16); any other "
                      "is exception 0x01." % ",".join(map(str, model.TABLE_FUNCTIONS))),
    click.option("--table-persist", cls=TableOption, key="persist", metavar="PATH",
                 default=model.TableConfig.persist, callback=parser(_parse_persist),
                 help="Keep the outputs and the free zone (0x0800-0x7FFF) in this file "
                      "across restarts, written atomically; a regular file in the state "
                      "directory ($STATE_DIRECTORY, else %s); off: not kept [default: "
                      "$STATE_DIRECTORY/table under the units, else not kept]."
                      % model.DEFAULT_STATE_DIRECTORY),
    click.option("--table-persist-interval", cls=TableOption, key="persist-interval",
                 type=click.IntRange(*model.PERSIST_INTERVAL_RANGE),
                 default=model.DEFAULT_PERSIST_INTERVAL_S, show_default=True, metavar="S",
                 help="With --table-persist: save changes at most every S seconds "
                      "(%d..%d), and at stop." % model.PERSIST_INTERVAL_RANGE),
)


PERSIST_OFF = "off"


PERSIST_FILE = "table"       # the default file's name in the state directory


def persist_path(value: str | None) -> str | None:
    """The table's file: the one given; none for "off"; when none is given, `table` in the
    state directory systemd gives the units (StateDirectory=, $STATE_DIRECTORY), else none
    (mbgw run by hand does not write somewhere it was not told to)."""
    if value is not None:
        return None if value == PERSIST_OFF else value
    state = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    return os.path.join(state, PERSIST_FILE) if state else None


def table_config(**settings) -> model.TableConfig:
    """TableConfig from the click values (table_enabled, table_functions, ...)."""
    fields = {"enabled": "table_enabled", "direct": "table_direct", "units": "table_units",
              "functions": "table_functions", "serial_functions": "table_serial_functions",
              "address": "table_address",
              "port": "table_port", "persist_interval_s": "table_persist_interval",
              "max_connections": "table_max_connections"}
    return convert("'--table'", lambda: model.TableConfig(
        persist=persist_path(settings.get("table_persist")),
        **{f: settings[o] for f, o in fields.items() if settings.get(o) is not None}))


def table_max_connections_option(help: str):
    """--table-max-connections ([table] max-connections); help: whose clients it counts."""
    return click.option(
        "--table-max-connections", cls=TableOption, key="table-max-connections",
        file_key="max-connections", type=click.IntRange(*model.MAX_CONNECTIONS_RANGE),
        default=model.DEFAULT_TABLE_MAX_CONNECTIONS, show_default=True, metavar="N", help=help)
