"""The mbgw command line (click): the mode commands, the configuration file's commands and
the operator's tools.  Nothing imports this package, and its modules never import its
__init__.

May import gateway, routing, slave, master, transparent, scenarios, upstream,
line, monitor, net, table, ops, protocol, config, firewall, web, northbound, besides errors
and audit.
See docs/architecture.md#the-packages.
"""
import click

from mbgw import __version__
from mbgw.cli import config, diag, scan, scenarios, table
from mbgw.cli.master import master
from mbgw.cli.slave import slave
from mbgw.cli.transparent import transparent


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="mbgw")
def main() -> None:
    """mbgw: a Modbus gateway between Modbus TCP and a Modbus RTU/ASCII serial line."""


main.add_command(slave)
main.add_command(master)
main.add_command(transparent)
config.register(main)   # run, check-config, config; --config on the mode commands
diag.register(main)     # status, clients, stats, trace
table.register(main)    # table read, table write
scenarios.register(main)  # scenarios, scenario enable|disable|test
scan.register(main)     # scan, probe: commissioning a bus
