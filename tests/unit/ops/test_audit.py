"""Audit events (mbgw/audit.py) as journald receives them: native records over a datagram
socket that stands in for /run/systemd/journal/socket, decoded here by the protocol's own
rules (systemd's "Native Journal Protocol": KEY=value lines; a value with a newline as KEY,
newline, 64-bit little-endian length, the bytes, newline), independently of mbgw's
encoder; and `--log-format json` lines.  The logging runs in a real subprocess whose stderr
is the journal stream by JOURNAL_STREAM's device and inode, as under systemd."""
import json
import logging
import os
import re
import socket
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from mbgw import audit
from mbgw.audit import Kind
from mbgw.ops import log
from tests.harness import CHECKOUT

# mbgw(1)'s hand-written part; the package build's test run has it beside tests/ (pybuild
# copies debian/pybuild.testfiles' entries by their base name)
H2M = next(p for p in (Path(CHECKOUT) / "debian" / "mbgw.h2m", Path(CHECKOUT) / "mbgw.h2m")
           if p.exists())


def decode(datagram: bytes) -> dict[str, str]:
    """One native journal record: its fields."""
    out, rest = {}, datagram
    while rest:
        line_end = rest.index(b"\n")
        line = rest[:line_end]
        if b"=" in line:
            key, value = line.split(b"=", 1)
            rest = rest[line_end + 1:]
        else:                                   # binary-safe form
            key = line
            (size,) = struct.unpack("<Q", rest[line_end + 1:line_end + 9])
            start = line_end + 9
            value = rest[start:start + size]
            assert rest[start + size:start + size + 1] == b"\n"
            rest = rest[start + size + 1:]
        assert re.fullmatch(rb"[A-Z0-9][A-Z0-9_]*", key), key
        out[key.decode()] = value.decode()
    return out


@pytest.fixture
def journal(tmp_path):
    """A datagram socket standing in for journald's; journal.records() the decoded ones."""
    path = str(tmp_path / "journal.socket")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(10)

    class Journal:
        socket_path = path

        def record(self) -> dict[str, str]:
            return decode(sock.recv(65536))

    yield Journal()
    sock.close()


def test_every_kind_has_its_own_128_bit_id_and_mbgw_1_lists_it():
    ids = [kind.message_id for kind in Kind]
    assert len(set(ids)) == len(ids)
    text = H2M.read_text().replace("\\-", "-")
    for kind in Kind:
        assert re.fullmatch(r"[0-9a-f]{32}", kind.message_id)
        assert kind.message_id in text and kind.label in text, kind


def test_an_event_is_a_native_record_with_its_id_and_fields(journal):
    logger = logging.getLogger("mbgw.test.audit")
    logger.propagate = False
    handler = log.JournalHandler(journal.socket_path)
    logger.addHandler(handler)
    try:
        audit.event(logger, Kind.FIREWALL_REFUSED, "firewall: refused client %s", "10.0.0.9:5",
                    client="10.0.0.9:5", rule="2", role=None)
        record = journal.record()
        logger.warning("first line\nsecond line")      # the binary-safe form
        multi = journal.record()
    finally:
        logger.removeHandler(handler)
        handler.close()
    assert record == {
        "MESSAGE": "mbgw.test.audit: firewall: refused client 10.0.0.9:5", "PRIORITY": "4",
        "SYSLOG_IDENTIFIER": "mbgw", "MBGW_LOGGER": "mbgw.test.audit",
        "MESSAGE_ID": Kind.FIREWALL_REFUSED.message_id, "MBGW_EVENT": "firewall-refused",
        "MBGW_CLIENT": "10.0.0.9:5", "MBGW_RULE": "2"}
    assert multi["MESSAGE"] == "mbgw.test.audit: first line\nsecond line"
    assert "MESSAGE_ID" not in multi and multi["PRIORITY"] == "4"


def _run_logging(tmp_path, code: str, journal_socket: str, as_journal: bool = True) -> str:
    """Run code after `from mbgw.ops import log` in a subprocess whose stderr is a file that
    JOURNAL_STREAM names (as_journal), with the journal's socket at journal_socket; its
    stderr."""
    stderr_path = tmp_path / "stderr.txt"
    stderr_path.touch()
    stat = os.stat(stderr_path)
    env = {k: v for k, v in os.environ.items() if k != "JOURNAL_STREAM"}
    if as_journal:
        env["JOURNAL_STREAM"] = f"{stat.st_dev}:{stat.st_ino}"
    program = (f"import logging; from mbgw import audit; from mbgw.ops import log; "
               f"log.JOURNAL_SOCKET = {journal_socket!r}; {code}")
    with open(stderr_path, "w") as stderr:
        subprocess.run([sys.executable, "-c", program], stderr=stderr, env=env, cwd=CHECKOUT,
                       check=True, timeout=30)
    return stderr_path.read_text()


def test_under_systemd_every_line_goes_to_the_journal_as_a_record(tmp_path, journal):
    stderr = _run_logging(tmp_path, (
        "log.setup('info'); "
        "audit.event(logging.getLogger('mbgw.web'), audit.Kind.LOGIN_FAILED, "
        "'web login failed for %r from %s', 'admin', '10.1.1.1', client='10.1.1.1', "
        "user='admin'); logging.getLogger('mbgw').info('plain line')"), journal.socket_path)
    assert stderr == ""
    event, plain = journal.record(), journal.record()
    assert event["MESSAGE"] == "mbgw.web: web login failed for 'admin' from 10.1.1.1"
    assert event["MESSAGE_ID"] == Kind.LOGIN_FAILED.message_id
    assert (event["PRIORITY"], event["MBGW_CLIENT"], event["MBGW_USER"]) == \
        ("4", "10.1.1.1", "admin")
    assert plain["MESSAGE"] == "mbgw: plain line" and plain["PRIORITY"] == "6"


def test_without_journald_the_journal_stream_gets_priority_lines(tmp_path):
    stderr = _run_logging(tmp_path, "log.setup('info'); logging.getLogger('mbgw').error('x')",
                          str(tmp_path / "no-journald"))
    assert stderr == "<3>mbgw: x\n"


def test_log_format_json_gives_the_same_fields_one_object_a_line(tmp_path, journal):
    stderr = _run_logging(tmp_path, (
        "log.setup('info', 'json'); "
        "audit.event(logging.getLogger('mbgw.control'), audit.Kind.COUNTERS_RESET, "
        "'counters reset by the operator (uid %s)', 0, user=0); "
        "logging.getLogger('mbgw').warning('two\\nlines')"), journal.socket_path)
    first, second = map(json.loads, stderr.splitlines())
    assert first["MESSAGE"] == "mbgw.control: counters reset by the operator (uid 0)"
    assert (first["MESSAGE_ID"], first["MBGW_EVENT"], first["MBGW_USER"], first["PRIORITY"]) \
        == (Kind.COUNTERS_RESET.message_id, "counters-reset", "0", "6")
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}\+00:00", first["TIMESTAMP"])
    assert second["MESSAGE"] == "mbgw: two\nlines" and "MESSAGE_ID" not in second


def test_config_set_leaves_an_audit_record_in_the_journal(tmp_path, journal, monkeypatch):
    from mbgw.cli import main
    monkeypatch.setattr(log, "JOURNAL_SOCKET", journal.socket_path)
    monkeypatch.setenv("SUDO_UID", "1000")
    path = tmp_path / "mbgw.toml"
    result = CliRunner().invoke(main, ["config", "set", "--config", str(path), "serial",
                                       "stout", "700"], prog_name="mbgw")
    assert result.exit_code == 0, result.output
    record = journal.record()
    assert record["MESSAGE_ID"] == Kind.CONFIG_CHANGED.message_id
    assert record["MBGW_SOURCE"] == "cli" and record["MBGW_KEYS"] == "serial.stout"
    assert record["MBGW_USER"] == f"uid {os.getuid()} (sudo from uid 1000)"
    assert record["MBGW_FILE"] == str(path)
    assert record["MESSAGE"] == (f"mbgw.config: configuration changed by mbgw config set "
                                 f"(uid {os.getuid()} (sudo from uid 1000)): {path}: "
                                 f"serial.stout")
