"""`mbgw config set|unset|default`: a key set with the guide's syntax, a key back to its
built-in default, or the whole file written with the factory defaults."""
from pathlib import Path

import click

from mbgw.cli import checks
from mbgw.cli.config_option import permission_failure, schema_of
from mbgw.cli.config_write import audit_change, change_file, say_how_to_apply, write_file
from mbgw.cli.file_options import file_options, file_path, file_words
from mbgw.cli.options import Failure
from mbgw.config.edit import changes_for_set
from mbgw.config.file import check, parse, read_text
from mbgw.config.schema import GROUPS, MODE_KEY
from mbgw.config.text import default_line, factory_text
from mbgw.config.toml_text import set_line, write_atomic
from mbgw.errors import ConfigFileError


@click.command("set")
@file_options
@click.argument("group", type=click.Choice(GROUPS))
@click.argument("param")
@click.argument("values", nargs=-1, required=True)
@click.pass_context
def set_(ctx, config_path: Path, instance: str | None, group: str, param: str,
         values: tuple) -> None:
    """Set PARAM of GROUP with the guide's syntax, e.g.

    \b
      mbgw config set serial stout 700
      mbgw config set serial format 8e1
      mbgw config set serial mode master       (clears net.authip and net.slaveid)
      mbgw config set serial mode rtu          (the protocol)
      mbgw config set net authip 1 192.168.1.5 (entry 1..8; 0.0.0.0 clears it)
      mbgw config set net slaveid 1 8 1 0 192.168.0.30   (master: FS LS FR M IP; FS 0 clears)
      mbgw config set net exception on
      mbgw config set general location Pump house 3   (the guide's set location)
    """
    path = file_path(ctx, config_path, instance)
    words = [group, param, *values, *file_words(ctx, path)]
    change_file(ctx, path, words, lambda schema, settings, data: changes_for_set(
        schema, settings, group, param, list(values)))


@click.command("unset")
@file_options
@click.argument("group", type=click.Choice(GROUPS))
@click.argument("param")
@click.pass_context
def unset(ctx, config_path: Path, instance: str | None, group: str, param: str) -> None:
    """Take PARAM out of the file: it goes back to its built-in default.  Works on a
    misspelt key too."""
    path = file_path(ctx, config_path, instance)
    words = [group, param, *file_words(ctx, path)]
    if group == "serial" and param == MODE_KEY:
        change_file(ctx, path, words, lambda schema, settings, data: changes_for_set(
            schema, settings, group, param, [schema.default_mode]))
    else:
        _unset(ctx, path, words, group, param)


def _unset(ctx, path: Path, words, group: str, param: str) -> None:
    """Works on the text, even when the key is unknown (a typo) or its value is bad."""
    schema = schema_of(ctx)
    try:
        text = read_text(path)
    except FileNotFoundError:
        click.echo(f"{path}: no such file: {group}.{param} is at its default")
        return
    except PermissionError:
        raise permission_failure(ctx, path, "read", words) from None
    data = _parse(path, text)
    group_data = data.get(group)
    content = group_data if isinstance(group_data, dict) else {}
    if param not in content:
        click.echo(f"{path}: {group}.{param} is not set: it is at its default")
        return
    serial_data = data.get("serial")
    serial = serial_data if isinstance(serial_data, dict) else {}
    known = schema.find(group, param)
    commented = default_line(schema, known.name,
                                         str(serial.get(MODE_KEY, ""))) if known else None
    new_text = set_line(text, group, param, None, commented)
    new_data = _parse(path, new_text)
    if param in new_data.get(group, {}):
        raise Failure(f"{path}: could not edit the file in place; nothing written")
    try:
        write_atomic(path, new_text)
    except PermissionError:
        raise permission_failure(ctx, path, "write", words) from None
    audit_change(ctx, path, f"{group}.{param}")
    click.echo(f"{path}: {group}.{param} back to its default")
    try:
        wrong, pending = checks.refusals(schema, check(schema, path, new_data))
        if wrong or pending:
            raise ConfigFileError(path, [*wrong, *pending])
    except ConfigFileError as err:
        raise Failure(f"{err}\n(the file still has these problems)") from None
    say_how_to_apply(path)


def _parse(path: Path, text: str) -> dict:
    try:
        return parse(path, text)
    except ConfigFileError as err:
        raise Failure(str(err)) from None


@click.command("default")
@file_options
@click.pass_context
def default(ctx, config_path: Path, instance: str | None) -> None:
    """Write the factory defaults: the guide's `set default`.  Every key is listed with its
    help, commented out at its built-in default; the device is /dev/ttyUSB0."""
    path = file_path(ctx, config_path, instance)
    write_file(ctx, path, factory_text(schema_of(ctx)), file_words(ctx, path),
               "factory defaults")
    click.echo(f"{path}: factory defaults written")
    say_how_to_apply(path)

