"""The steps every `mbgw config` change takes: read and check the file (or start from the
factory file), check the result as `mbgw run` would, write it atomically with an audit event
in the journal, warn of what is still missing, and say how the service takes it."""
import tomllib
from pathlib import Path

import click

from mbgw.cli import checks
from mbgw.cli.config_option import command_line, permission_failure, schema_of
from mbgw.cli.file_options import file_words
from mbgw.cli.options import Failure
from mbgw.config import schema as config_schema  # DEFAULT_PATH, CONFIG_DIR read at each call
from mbgw.config.edit import REMOVE, apply_changes
from mbgw.config.file import Settings, check, parse, read_text
from mbgw.config.schema import MODE_KEY, Schema
from mbgw.config.text import edit, factory_text
from mbgw.config.toml_text import dump_value, write_atomic
from mbgw.errors import ConfigError, ConfigFileError


def say_how_to_apply(path: Path) -> None:
    """Print the command that makes the running service take the file, when it is a
    service's file."""
    if path == config_schema.DEFAULT_PATH:
        click.echo("apply it with: systemctl reload mbgw")
    elif path.parent == config_schema.CONFIG_DIR and path.suffix == ".toml":
        click.echo(f"apply it with: systemctl reload mbgw@{path.stem}")


def write_file(ctx, path: Path, text: str, words, what: str) -> None:
    """Write the file; what: the change, for the journal's audit event."""
    try:
        write_atomic(path, text)
    except PermissionError:
        raise permission_failure(ctx, path, "write", words) from None
    except OSError as err:
        raise Failure(f"cannot write {path}: {err.strerror or err}") from None
    audit_change(ctx, path, what)


def audit_change(ctx, path: Path, what: str) -> None:
    """A change of the file as an audit event in the journal (journald adds the sender's
    _UID, _PID and _COMM itself); nothing on a machine without one."""
    import os

    from mbgw.audit import Kind
    from mbgw.ops.log import journal_event
    user = f"uid {os.getuid()}"
    if os.environ.get("SUDO_UID"):
        user += f" (sudo from uid {os.environ['SUDO_UID']})"
    journal_event("mbgw.config", Kind.CONFIG_CHANGED,
                  f"configuration changed by {ctx.command_path} ({user}): {path}: {what}",
                  source="cli", user=user, keys=what, file=str(path))


def read_checked(ctx, schema: Schema, path: Path, words) -> tuple[str, dict, Settings]:
    """The file's text, its data and its checked settings (the factory file's when there is
    none yet); a file that does not pass its check stops the edit."""
    try:
        text = read_text(path)
    except FileNotFoundError:
        text = factory_text(schema)
    except PermissionError:
        raise permission_failure(ctx, path, "read", words) from None
    try:
        data = parse(path, text)
        return text, data, check(schema, path, data)
    except ConfigFileError as err:
        group = ctx.parent
        while group.parent is not None and group.command.name != "config":
            group = group.parent
        raise Failure(f"{err}\nmbgw: fix the file first (or start again: "
                      f"{command_line(group, 'default', *file_words(ctx, path))})") \
            from None


def change_file(ctx, path: Path, words, change, shown: bool = True) -> None:
    """Read the file (or start from the factory file), make `change(schema, settings, data)`
    -> {key: value}, check the whole result, write it atomically, say what changed (its
    value too when `shown`)."""
    schema = schema_of(ctx)
    text, data, settings = read_checked(ctx, schema, path, words)
    try:
        changes = change(schema, settings, data)
        new_data = apply_changes(data, schema, changes)
        pending = start_check(schema, path, new_data)
    except ConfigError as err:
        raise refused(path, err) from None
    new_mode = changes.get(MODE_KEY, settings.mode)
    new_text = edit(text, schema, new_mode, changes)
    if tomllib.loads(new_text) != new_data:          # the editor's own check
        raise Failure(f"{path}: could not edit the file in place; nothing written")
    labels = {name: schema.label(name) if name == MODE_KEY or name in schema.keys else name
              for name in changes}
    write_file(ctx, path, new_text, words, ", ".join(labels.values()))
    for name, value in changes.items():
        label = labels[name]
        if value is REMOVE:
            click.echo(f"{path}: {label} back to its default")
        elif not shown:
            click.echo(f"{path}: {label} set")
        else:
            click.echo(f"{path}: {label} = {dump_value(value)}")
    warn_pending(path, pending)
    if text != new_text and not pending:
        say_how_to_apply(path)


def start_check(schema: Schema, path: Path, data: dict) -> list[str]:
    """The checks of the file and of `mbgw run` (mbgw.cli.checks) on an edit's result:
    raises ConfigError on a problem the edit must not write; the keys that do not go
    together yet (another `set` mends them)."""
    wrong, pending = checks.refusals(schema, check(schema, path, data))
    if wrong:
        raise ConfigFileError(path, [*wrong, "nothing written"])
    return pending


def refused(path: Path, err: ConfigError) -> Failure:
    lines = str(err).splitlines()
    return Failure("\n".join(line if line.startswith(str(path)) else f"{path}: {line}"
                             for line in lines))


def warn_pending(path: Path, pending: list[str]) -> None:
    """Written, but the service would not start it, nor take it on a reload, yet."""
    for problem in pending:
        click.echo(f"mbgw: warning: {path}: {problem}", err=True)
    if pending:
        click.echo(f"mbgw: warning: {path}: mbgw run and systemctl reload refuse the file "
                   f"until this is set; mbgw check-config checks it", err=True)
