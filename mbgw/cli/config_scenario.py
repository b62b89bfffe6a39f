"""`mbgw config scenario add|remove`: the [[scenario]] tables of the configuration file."""
from pathlib import Path

import click

from mbgw.cli.config_option import schema_of
from mbgw.cli.config_write import (
    read_checked,
    refused,
    say_how_to_apply,
    start_check,
    warn_pending,
    write_file,
)
from mbgw.cli.file_options import file_options, file_path, file_words
from mbgw.config import scenario as scenario_config
from mbgw.config import scenario_text
from mbgw.config.file import SCENARIO_KEY, check, parse
from mbgw.errors import ConfigError


@click.group("scenario")
def config_scenario() -> None:
    """Add and remove the [[scenario]] tables of the configuration file: requests the gateway
    sends on its own (see mbgw.toml(5), SCENARIOS).  Checked like the file; the running
    service takes them on `systemctl reload mbgw`."""


@config_scenario.command("add")
@file_options
@click.argument("name")
@click.argument("keys", nargs=-1, required=True, metavar="KEY=VALUE...")
@click.pass_context
def scenario_add(ctx, config_path: Path, instance: str | None, name: str, keys: tuple) -> None:
    """Add scenario NAME with the keys of a [[scenario]] table: slave (serial) or server
    and unit (TCP), function, address, quantity, table, cycle (ms) or trigger=change, and
    retries, stale-after, enabled, send-unwritten; function 23: read-address,
    read-quantity, read-table, write-address, write-quantity, write-table.  See
    mbgw.toml(5), SCENARIOS.  E.g.

    \b
      mbgw config scenario add boiler-temps slave=45 function=3 address=1000 quantity=10 \\
          table=0 cycle=3000
      mbgw config scenario add valve server=192.168.10.45 function=5 address=7 \\
          table=100.0 trigger=change
    """
    path = file_path(ctx, config_path, instance)
    words = ["scenario", "add", name, *keys, *file_words(ctx, path)]

    def change(text: str, data: dict) -> str:
        fields = scenario_text.parse_words(keys)
        if "name" in fields:
            raise ConfigError("name: give it once, as NAME, not as a KEY=VALUE")
        scenario = scenario_config.parse_scenario({"name": name, **fields}, f"scenario {name}")
        if any(e.get("name") == name for e in data.get(SCENARIO_KEY, [])
               if isinstance(e, dict)):
            raise ConfigError(f"scenario {name}: already there (mbgw config scenario remove "
                              f"{name} first)")
        return scenario_text.add(text, scenario.fields())
    _edit_scenarios(ctx, path, words, change, f"scenario {name} added")


@config_scenario.command("remove")
@file_options
@click.argument("name")
@click.pass_context
def scenario_remove(ctx, config_path: Path, instance: str | None, name: str) -> None:
    """Take scenario NAME out of the file."""
    path = file_path(ctx, config_path, instance)
    words = ["scenario", "remove", name, *file_words(ctx, path)]

    def change(text: str, data: dict) -> str:
        new_text = scenario_text.remove(text, name)
        if new_text is None:
            names = [e.get("name") for e in data.get(SCENARIO_KEY, []) if isinstance(e, dict)]
            raise ConfigError(f"no scenario {name!r}" +
                              (f" (scenarios: {', '.join(map(str, names))})" if names else ""))
        return new_text
    _edit_scenarios(ctx, path, words, change, f"scenario {name} removed")


def _edit_scenarios(ctx, path: Path, words, change, done: str) -> None:
    """Read and check the file (or start from the factory file), new_text = change(text,
    data), check the result as a whole, write it atomically."""
    schema = schema_of(ctx)
    text, data, _ = read_checked(ctx, schema, path, words)
    try:
        new_text = change(text, data)
        pending = start_check(schema, path, parse(path, new_text))
    except ConfigError as err:
        raise refused(path, err) from None
    write_file(ctx, path, new_text, words, done)
    click.echo(f"{path}: {done}")
    scenarios = check(schema, path, parse(path, new_text)).scenarios
    for warning in scenario_config.overlaps(scenarios):
        click.echo(f"mbgw: warning: {path}: {warning}", err=True)
    warn_pending(path, pending)
    if not pending:
        say_how_to_apply(path)
