"""The configuration-file commands: `mbgw run`, `mbgw check-config`, `mbgw config show|set|
unset|default|password|scenario`, and the --config option of the mode commands.
register(main) adds them."""
import click

from mbgw.cli.config_option import add_to_mode_commands
from mbgw.cli.config_password import password
from mbgw.cli.config_scenario import config_scenario
from mbgw.cli.config_set import default, set_, unset
from mbgw.cli.config_show import show
from mbgw.cli.run import check_config, run


@click.group("config", commands=[show, set_, unset, default, password, config_scenario])
def config() -> None:
    """Show and change the configuration file with the ACKSYS commands: `mbgw config set
    serial stout 700` is the guide's `set serial stout 700`.  Each change is checked like the
    command line and written atomically; the running service takes it on `systemctl reload
    mbgw`."""


def register(root: click.Group) -> None:
    """Add the commands to `root`, and a --config FILE option to its mode commands."""
    add_to_mode_commands(root)
    for command in (run, check_config, config):
        root.add_command(command)
