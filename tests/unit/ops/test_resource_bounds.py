"""What a configuration file or an attacker cannot make mbgw do: write the table's file
outside the state directory or into a link, device or FIFO; nest a file deeper than any key
needs; and the helpers every listener shares (mbgw.ops.limits)."""
import errno
import logging
import os
import socket
import threading

import pytest
from click.testing import CliRunner

from mbgw.cli import main
from mbgw.cli.options import EX_CONFIG
from mbgw.errors import ConfigError
from mbgw.ops.limits import REST_FIRST_S, REST_MAX_S, AcceptRest, WarnLimit
from mbgw.table.memory import Table
from mbgw.table.persist import Persistence


def mbgw(*args, **env):
    return CliRunner().invoke(main, [str(a) for a in args], prog_name="mbgw", env=env or None)


def config_with_persist(tmp_path, persist: str):
    path = tmp_path / "mbgw.toml"
    path.write_text(f'[serial]\ndevice = "/dev/ttyS0"\n[table]\nenabled = true\n'
                    f'persist = "{persist}"\n')
    return path


@pytest.fixture
def state(tmp_path):
    directory = tmp_path / "state"
    directory.mkdir()
    return directory


def test_check_config_accepts_a_file_in_the_state_directory(tmp_path, state):
    result = mbgw("check-config", config_with_persist(tmp_path, f"{state}/table"),
                  STATE_DIRECTORY=str(state))
    assert result.exit_code == 0, result.output


@pytest.mark.parametrize("where, why", [
    ("/etc/passwd", "outside the state directory"),
    ("/dev/zero", "not a regular file"),
    ("{state}/../escape", "outside the state directory"),
    ("table", "not an absolute path"),
])
def test_check_config_refuses_a_file_outside_the_state_directory(tmp_path, state, where, why):
    result = mbgw("check-config", config_with_persist(tmp_path, where.format(state=state)),
                  STATE_DIRECTORY=str(state))
    assert result.exit_code == EX_CONFIG
    assert "table.persist" in result.output and why in result.output, result.output


def test_the_default_state_directory_is_var_lib_mbgw(tmp_path):
    result = mbgw("check-config", config_with_persist(tmp_path, str(tmp_path / "table")))
    assert result.exit_code == EX_CONFIG and "outside the state directory /var/lib/mbgw" in \
        result.output


@pytest.mark.parametrize("kind", ["fifo", "link", "directory"])
def test_check_config_refuses_what_is_not_a_regular_file(tmp_path, state, kind):
    target = state / "table"
    if kind == "fifo":
        os.mkfifo(target)
    elif kind == "link":
        os.symlink("/dev/zero", target)
    else:
        target.mkdir()
    result = mbgw("check-config", config_with_persist(tmp_path, str(target)),
                  STATE_DIRECTORY=str(state))
    assert result.exit_code == EX_CONFIG and "not a regular file" in result.output, result.output


def test_a_link_out_of_the_state_directory_is_outside_it(tmp_path, state):
    os.symlink(tmp_path, state / "out")
    result = mbgw("check-config", config_with_persist(tmp_path, f"{state}/out/table"),
                  STATE_DIRECTORY=str(state))
    assert result.exit_code == EX_CONFIG and "outside the state directory" in result.output


def test_run_refuses_a_file_nested_too_deep_with_78(tmp_path):
    path = tmp_path / "deep.toml"
    path.write_text('[serial]\ndevice = "/dev/ttyS0"\n[net]\nauthip = '
                    + "[" * 5000 + "]" * 5000 + "\n")
    result = mbgw("run", "--config", path)
    assert result.exit_code == 78, result.output
    assert "nested more than 8 deep" in result.output
    assert mbgw("check-config", path).exit_code == EX_CONFIG


@pytest.mark.parametrize("kind", ["fifo", "link"])
def test_persistence_never_reads_a_fifo_or_a_link_swapped_in(tmp_path, kind):
    path = tmp_path / "table"
    if kind == "fifo":
        os.mkfifo(path)
    else:
        (tmp_path / "elsewhere").write_bytes(b"x")
        os.symlink(tmp_path / "elsewhere", path)
    done = []
    loader = threading.Thread(target=lambda: done.append(_load_error(path)), daemon=True)
    loader.start()
    loader.join(5)
    assert done and "must be a regular file" in done[0]     # refused, and at once


def _load_error(path) -> str:
    try:
        Persistence(Table(), path, 10).load()
    except ConfigError as err:
        return str(err)
    return ""


def test_persistence_never_writes_through_a_link_put_at_its_temporary_file(tmp_path):
    table = Table()
    table.write(0x0800, [1, 2])
    path = tmp_path / "table"
    victim = tmp_path / "victim"
    victim.write_text("keep me")
    os.symlink(victim, tmp_path / "table.tmp")
    assert Persistence(table, path, 10).save()
    assert victim.read_text() == "keep me"
    assert path.is_file() and not path.is_symlink()


def test_a_warning_per_address_and_reason_once_an_interval_with_the_count(caplog):
    warn = WarnLimit(logging.getLogger("mbgw.test"))
    with caplog.at_level(logging.WARNING, "mbgw.test"):
        for _ in range(5):
            warn.warn("10.0.0.1", "busy", "refused %s", "a")
        warn.warn("10.0.0.1", "bad header", "bad %s", "b")
        warn.warn("10.0.0.2", "busy", "refused %s", "c")
    assert [r.getMessage().split(" (")[0] for r in caplog.records] == \
        ["refused a", "bad b", "refused c"]
    warn._interval_s = 0
    with caplog.at_level(logging.WARNING, "mbgw.test"):
        warn.warn("10.0.0.1", "busy", "refused %s", "d")
    assert "(4 more like it left out)" in caplog.records[-1].getMessage()


def test_accept_failures_rest_the_listener_and_are_logged_once(caplog):
    rest = AcceptRest(logging.getLogger("mbgw.test"), "Modbus TCP")
    err = OSError(errno.EMFILE, os.strerror(errno.EMFILE))
    with caplog.at_level(logging.INFO, "mbgw.test"):
        rests = [rest.failed(err) for _ in range(1000)]
        rest.accepted()
    assert rests[0] > 0 and max(rests) == REST_MAX_S and rests == sorted(rests)
    messages = [r.getMessage() for r in caplog.records]
    assert len(messages) == 2
    assert "Too many open files" in messages[0] and "1000 accept() failed" in messages[1]


class OutOfDescriptors:
    """A listener whose accept() fails as a process at its RLIMIT_NOFILE does."""

    def accept(self):
        raise OSError(errno.EMFILE, os.strerror(errno.EMFILE))


def test_accept_rests_a_listener_out_of_descriptors_then_takes_a_newcomer():
    rest = AcceptRest(logging.getLogger("mbgw.test"), "Modbus TCP")
    rested: list[float] = []
    assert rest.accept(OutOfDescriptors(), rested.append) is None
    assert rested == [REST_FIRST_S] and rest.failures == 1
    with socket.create_server(("127.0.0.1", 0)) as listener:
        listener.setblocking(False)
        assert rest.accept(listener, rested.append) is None     # nobody waits: no rest
        with socket.create_connection(listener.getsockname()) as client:
            accepted = rest.accept(listener, rested.append)
            assert accepted is not None
            sock, address = accepted
            with sock:
                assert address == client.getsockname()
    assert rested == [REST_FIRST_S] and rest.failures == 0


def test_check_config_refuses_https_only_without_a_certificate(tmp_path):
    path = tmp_path / "mbgw.toml"
    path.write_text('[serial]\ndevice = "/dev/ttyS0"\n[web]\nhttps-only = true\n')
    result = mbgw("check-config", path)
    assert result.exit_code == EX_CONFIG and "web.https-only: needs HTTPS" in result.output


def test_check_config_accepts_https_only_with_a_certificate(tmp_path):
    import subprocess
    cert, key = tmp_path / "web.pem", tmp_path / "web.key"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout",
                    str(key), "-out", str(cert), "-days", "2", "-subj", "/CN=localhost"],
                   check=True, capture_output=True, timeout=60)
    path = tmp_path / "mbgw.toml"
    path.write_text(f'[serial]\ndevice = "/dev/ttyS0"\n[web]\nhttps-only = true\n'
                    f'cert = "{cert}"\nkey = "{key}"\n')
    result = mbgw("check-config", path)
    assert result.exit_code == 0, result.output
