"""`mbgw config password`: the web console's passwords, kept as salted hashes in a file
closed to other local users."""
from pathlib import Path

import click

from mbgw.cli.config_write import change_file
from mbgw.cli.file_options import file_options, file_path, file_words
from mbgw.cli.options import Failure
from mbgw.errors import ConfigError

SERVICE_GROUP = "mbgw"       # the service's user and group (debian/mbgw.sysusers)


@click.command("password")
@file_options
@click.argument("role", type=click.Choice(["admin", "user"]))
@click.option("--stdin", "from_stdin", is_flag=True,
              help="Read the password from the first line of standard input (scripts, tests).")
@click.pass_context
def password(ctx, config_path: Path, instance: str | None, role: str, from_stdin: bool) -> None:
    """Set the web console's password of ROLE (admin: changes; user: reads), prompted twice;
    the file keeps its salted scrypt hash (web.admin-password, web.user-password), which
    `config show` never shows."""
    from mbgw.web.passwords import hash_password
    path = file_path(ctx, config_path, instance)
    text = _read_password(from_stdin)
    try:
        stored = hash_password(text)
    except ConfigError as err:
        raise Failure(str(err)) from None
    change_file(ctx, path, ["password", role, *file_words(ctx, path)],
                lambda schema, settings, data: {f"{role}-password": stored}, shown=False)
    _keep_from_others(path)


def _keep_from_others(path: Path) -> None:
    """A file with password hashes is not for every local user: no access for others; its
    group becomes the service's (mbgw, which reads it) when root sets the password."""
    import grp
    import os
    import stat
    try:
        group = grp.getgrnam(SERVICE_GROUP).gr_gid if os.geteuid() == 0 else None
    except KeyError:
        group = None
    try:
        if group is not None:
            os.chown(path, -1, group)
        os.chmod(path, stat.S_IMODE(os.stat(path).st_mode) & ~0o007 | 0o040 * (group is not None))
    except OSError as err:
        raise Failure(f"{path}: the hash is written, but the file could not be closed to "
                      f"other users: {err.strerror}") from None


def _read_password(from_stdin: bool) -> str:
    import getpass
    import sys
    if from_stdin:
        return sys.stdin.readline().rstrip("\r\n")
    first = getpass.getpass("New password: ")
    if getpass.getpass("Again: ") != first:
        raise Failure("the passwords differ; nothing written")
    return first
