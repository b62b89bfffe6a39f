"""The file options of the commands that read or change the configuration file (run,
check-config, config ..., the operator's tools): --config FILE or -i NAME (the file of the
service instance mbgw@NAME), and what a suggested command repeats of them."""
from pathlib import Path

import click

from mbgw.config import schema as config_schema  # DEFAULT_PATH, CONFIG_DIR read at each call


def file_options(function):
    """-i/--instance NAME and --config FILE on a command (its parameters instance and
    config_path; file_path makes one path of them)."""
    function = click.option(
        "-i", "--instance", metavar="NAME",
        help=f"The file of the service instance mbgw@NAME: "
             f"{config_schema.CONFIG_DIR}/NAME.toml.")(function)
    return click.option(
        "--config", "config_path", metavar="FILE", envvar="MBGW_CONFIG",
        type=click.Path(dir_okay=False, path_type=Path), default=config_schema.DEFAULT_PATH,
        show_default=True, help="The configuration file (also $MBGW_CONFIG).")(function)


def file_path(ctx: click.Context, config_path: Path, instance: str | None) -> Path:
    """The file the options name; a usage error when both are given."""
    if instance is None:
        return Path(config_path)
    if ctx.get_parameter_source("config_path") == click.core.ParameterSource.COMMANDLINE:
        raise click.UsageError("give --config or --instance, not both")
    return config_schema.CONFIG_DIR / f"{check_instance(instance)}.toml"


def check_instance(instance: str) -> str:
    """NAME of the service instance mbgw@NAME; a usage error when it cannot be one."""
    if not instance or "/" in instance or instance.startswith("."):
        raise click.BadParameter(f"{instance!r}: a name such as ttyUSB1",
                                 param_hint="'--instance'")
    return instance


def file_words(ctx: click.Context, path: Path) -> list[str]:
    """The file options to repeat in a suggested command."""
    return [] if path == config_schema.DEFAULT_PATH else ["--config", str(path)]
