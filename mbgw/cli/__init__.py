"""The mbgw command line (click): the mode commands, the configuration file's commands and
the operator's tools.  Options carry the ACKSYS command names and defaults; nothing imports
this package, and its modules never import its __init__."""
import click

from mbgw import __version__
from mbgw.cli import config, diag, scenarios, table
from mbgw.cli.master import master
from mbgw.cli.slave import slave


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="mbgw")
def main() -> None:
    """mbgw: a Modbus gateway between Modbus TCP and a Modbus RTU/ASCII serial line."""


main.add_command(slave)
main.add_command(master)
config.register(main)   # run, check-config, config; --config on the mode commands
diag.register(main)     # status, clients, stats, trace
table.register(main)    # table read, table write
scenarios.register(main)  # scenarios, scenario enable|disable|test
