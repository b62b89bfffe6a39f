"""`mbgw config show`: the settings in effect (all, a group or a key), the scenarios, the
[[line]] and [[route]] tables with the implicit routes, or the security settings in force."""
from pathlib import Path

import click

from mbgw.cli import checks
from mbgw.cli.config_option import load_settings, schema_of
from mbgw.cli.file_options import file_options, file_path, file_words
from mbgw.config import line_file, scenario_text
from mbgw.config.edit import show_lines
from mbgw.config.file import SCENARIO_KEY, Settings
from mbgw.config.lines import LINE_MODES, TCP_FACE
from mbgw.config.monitor import MONITOR_TABLE, map_fields
from mbgw.config.number_list import number_list_text
from mbgw.config.route_plan import implicit_routes
from mbgw.config.schema import GROUPS, MODE_KEY, Schema
from mbgw.config.toml_text import dump_value
from mbgw.errors import ConfigError

SHOW_WIDTH = 16                    # the key column of `mbgw config show`


@click.command("show")
@file_options
@click.option("--security", is_flag=True,
              help="The security settings in force instead: listeners (address, port, plain "
                   "or TLS, limits), TLS versions and suites, CRL, authip, the firewall, the "
                   "web console (which passwords are set, never their hashes), the control "
                   "socket, and who may read the file.")
@click.option("--json", "as_json", is_flag=True, help="With --security: as a JSON document.")
@click.argument("group", required=False, type=click.Choice(
    [*GROUPS, SCENARIO_KEY, line_file.LINE_TABLE, line_file.ROUTE_TABLE, MONITOR_TABLE,
     line_file.DEVICE_TABLE]))
@click.argument("param", required=False)
@click.pass_context
def show(ctx, config_path: Path, instance: str | None, security: bool, as_json: bool,
         group: str | None, param: str | None) -> None:
    """Show the settings in effect (the file's, else the built-in defaults): all, one GROUP
    (serial, net, general, table), or one PARAM, like the guide's `show serial stout`;
    `show scenario [NAME]`: the scenarios; `show line [NAME]`: the [[line]] tables; `show
    route`: the [[route]] tables, then the implicit routes (today's routing of a face without
    a route) as comments; `show monitor`: the [[monitor]] maps; `show device`: the [[device]]
    tables; `show --security [--json]`:
    the security settings in force."""
    if as_json and not security:
        raise click.UsageError("--json goes with --security")
    if security and group is not None:
        raise click.UsageError("--security shows them all: give no GROUP")
    path = file_path(ctx, config_path, instance)
    schema = schema_of(ctx)
    if path.exists():
        settings = load_settings(ctx, schema, path, [*filter(None, (group, param)),
                                                     *(["--security"] if security else []),
                                                     *file_words(ctx, path)])
    else:
        click.echo(f"mbgw: {path} does not exist: built-in defaults", err=True)
        settings = Settings(path, schema.default_mode, {})
    if security:
        _show_security(schema, settings, as_json)
    elif not _show_tables(schema, settings, group, param):
        _show_groups(schema, settings, group, param)


def _show_tables(schema: Schema, settings: Settings, group: str | None,
                 param: str | None) -> bool:
    """`show scenario|line|route|device [NAME]`: True when group was one of those."""
    if group == SCENARIO_KEY:
        _show_scenarios(settings, param)
    elif group == line_file.LINE_TABLE:
        _show_lines(settings, param, separate=False)
    elif group == line_file.ROUTE_TABLE:
        _show_routes(schema, settings, separate=False)
    elif group == MONITOR_TABLE:
        _echo_tables(MONITOR_TABLE, [map_fields(m) for m in settings.monitors], False)
    elif group == line_file.DEVICE_TABLE:
        _echo_tables(line_file.DEVICE_TABLE,
                     [line_file.device_fields(d) for d in settings.devices], False)
    else:
        return False
    return True


def _show_groups(schema: Schema, settings: Settings, group: str | None,
                 param: str | None) -> None:
    if param is not None:
        name = param.lower()
        key = schema.find(group, name) if group else None
        if key is None and not (group == "serial" and name == MODE_KEY):
            raise click.BadParameter(f"{group}.{param}: unknown{schema.hint(name)}",
                                     param_hint="PARAM")
        name = key.name if key is not None else name
        for line in show_lines(schema, settings, name):
            click.echo(line)
        return
    for shown in [group] if group else GROUPS:
        names = schema.group_keys(shown)
        if not names:
            continue
        click.echo(f"[{shown}]")
        for name in names:
            for line in show_lines(schema, settings, name):
                click.echo(f"{schema.file_name(name):<{SHOW_WIDTH}} {line}")
    if group is None and settings.scenarios:
        _show_scenarios(settings, None)
    if group is None and settings.lines:
        _show_lines(settings, None)
    if group is None and (settings.routes or settings.lines):
        _show_routes(schema, settings)
    if group is None:
        _echo_tables(MONITOR_TABLE, [map_fields(m) for m in settings.monitors])
        _echo_tables(line_file.DEVICE_TABLE,
                     [line_file.device_fields(d) for d in settings.devices])


def _show_security(schema: Schema, settings: Settings, as_json: bool) -> None:
    import json

    from mbgw.cli import security
    found = security.report(schema, settings)
    if as_json:
        click.echo(json.dumps(found, indent=2))
    else:
        for line in security.text(found):
            click.echo(line)


def _show_scenarios(settings: Settings, name: str | None) -> None:
    shown = [sc for sc in settings.scenarios if name is None or sc.name == name]
    if name is not None and not shown:
        names = ", ".join(sc.name for sc in settings.scenarios)
        raise click.BadParameter(f"no scenario {name!r} in {settings.path}"
                                 + (f" (scenarios: {names})" if names else ""),
                                 param_hint="NAME")
    for number, sc in enumerate(shown):
        if number:
            click.echo()
        for line in scenario_text.block(sc.fields()):
            click.echo(line)


def _show_lines(settings: Settings, name: str | None, separate: bool = True) -> None:
    shown = [line for line in settings.lines if name is None or line.name == name]
    if name is not None and not shown:
        names = ", ".join(line.name for line in settings.lines)
        raise click.BadParameter(f"no line {name!r} in {settings.path}"
                                 + (f" (lines: {names})" if names else ""), param_hint="NAME")
    _echo_tables("line", [line_file.line_fields(line) for line in shown], separate)


def _echo_tables(name: str, tables: list[dict], separate: bool = True) -> None:
    """Each of tables as a [[name]] table of the file (separate: a blank line before the
    first too)."""
    for number, fields in enumerate(tables):
        if separate or number:
            click.echo()
        click.echo(f"[[{name}]]")
        for key, value in fields.items():
            click.echo(f"{key} = {dump_value(value)}")


def _show_routes(schema: Schema, settings: Settings, separate: bool = True) -> None:
    """The [[route]] tables, then the implicit routes in force beside them (when the file
    would start: else only the tables)."""
    _echo_tables("route", [line_file.route_fields(route) for route in settings.routes],
                 separate)
    try:
        cfg = checks.check_file(schema, settings)
    except (ConfigError, click.ClickException):
        return
    implicit = implicit_routes(cfg) if settings.mode in LINE_MODES else ()
    if implicit and (separate or settings.routes):
        click.echo()
    for route in implicit:
        face = f"from {route.face}: " if route.face != TCP_FACE else ""
        click.echo(f"# implicit ({route.label}): {face}units "
                   f"{number_list_text(route.units)} -> {route.target}"
                   + (f" offset {route.offset}" if route.offset else "")
                   + (f" address {route.address}" if route.address is not None else ""))
