"""`mbgw scenarios`, `mbgw scenario enable|disable NAME [--save]`, `mbgw scenario test
KEY=VALUE...`: the running daemon's scenarios through its control socket
(mbgw.scenarios.control answers)."""
import json
import time

import click

from mbgw.cli.diag import ask, control_option
from mbgw.cli.options import Failure
from mbgw.cli.render_scenarios import format_scenarios
from mbgw.config.scenario_text import parse_words
from mbgw.errors import ConfigError

TEST_TIMEOUT_S = 90.0       # the daemon waits up to 60 s for its runner


def _ask(control: str | None, instance: str | None, request: dict,
         timeout: float = 5.0) -> dict:
    try:
        return ask(control, instance, request, timeout)
    except Failure as failure:
        if f"unknown command {request['command']!r}" in failure.message:
            raise Failure("the daemon runs no scenarios (this mbgw is older, or has none "
                          "configured)") from None
        raise


@click.command("scenarios")
@click.option("--json", "as_json", is_flag=True, help="Print the scenarios as JSON.")
@control_option
def scenarios(as_json: bool, control: str | None, instance: str | None) -> None:
    """The running daemon's scenarios: state (starting, running, error with VPGate's
    message, disabled), runs, errors, retries, overruns, last success, data age."""
    reply = _ask(control, instance, {"command": "scenarios"})
    if as_json:
        click.echo(json.dumps(reply["scenarios"], indent=2))
    else:
        click.echo("\n".join(format_scenarios(reply["scenarios"], time.time())))


def _switch(on: bool) -> click.Command:
    """`scenario enable` (on) or `scenario disable`."""
    word = "enable" if on else "disable"

    @click.command(word, help=f"{word.capitalize()} scenario NAME at once (VPGate's Enabled "
                              f"box); --save keeps it across reloads.")
    @click.argument("name")
    @click.option("--save", is_flag=True,
                  help="Also write it to the configuration file (enabled = false, or "
                       "the key taken out); without it, until the next reload.")
    @control_option
    def command(name: str, save: bool, control: str | None, instance: str | None) -> None:
        reply = _ask(control, instance, {"command": f"scenario-{word}", "name": name,
                                         "save": save})
        click.echo(f"scenario {name} {word}d" +
                   (", saved in the configuration file" if reply.get("saved")
                    else " until the next reload"))
    return command


@click.command("test", context_settings={"ignore_unknown_options": True})
@click.argument("keys", nargs=-1, required=True, metavar="KEY=VALUE...")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
@control_option
def scenario_test(keys: tuple, as_json: bool, control: str | None, instance: str | None) -> None:
    """Run a scenario once on the running daemon's line or TCP client (VPGate's TEST
    button) and print the result and the data, without changing the configuration.
    The keys of a [[scenario]] table; name, cycle and trigger may be left out, e.g.

    \b
      mbgw scenario test slave=45 function=3 address=1000 quantity=10 table=0
      mbgw scenario test server=192.168.10.45 function=16 address=0 quantity=2 table=100

    A write sends the table's data; a read's data is printed, not stored."""
    try:
        fields = parse_words(keys)
    except ConfigError as err:
        raise click.BadParameter(str(err), param_hint="KEY=VALUE") from None
    reply = _ask(control, instance, {"command": "scenario-test", "fields": fields},
                 TEST_TIMEOUT_S)
    if as_json:
        click.echo(json.dumps(reply, indent=2))
        return
    click.echo("\n".join(format_test(reply)))
    if not reply["ok"]:
        raise click.exceptions.Exit(1)


@click.group("scenario", commands=[_switch(True), _switch(False), scenario_test])
def scenario() -> None:
    """Enable, disable or test a scenario of the running daemon."""


def register(main: click.Group) -> None:
    main.add_command(scenarios)
    main.add_command(scenario)


def format_test(r: dict) -> list[str]:
    lines = [f"{'ok' if r['ok'] else 'error'}: {r['message']} ({r['latency_ms']:.1f} ms"
             + (f", {r['retries']} retries" if r["retries"] else "") + ")",
             f"request  {r['request']}",
             f"reply    {r['reply'] if r['reply'] is not None else '-'}"]
    if r["data"]:
        sc = r["scenario"]
        first = sc.get("address", sc.get("read-address", 0))
        lines.append(f"data     ({len(r['data'])} from {first})")
        for i in range(0, len(r["data"]), 10):
            lines.append("  " + " ".join(f"{v:>5}" for v in r["data"][i:i + 10]))
    return lines
