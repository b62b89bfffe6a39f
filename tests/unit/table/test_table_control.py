"""The operator's access to the exchange table: the control commands "table-read" and
"table-write" (mbgw.table.control) on a real Table, and `mbgw table read|write` through a real
control socket served by mbgw.ops.control.ControlServer in a thread."""
import asyncio
import json
import logging
import threading

import pytest
from click.testing import CliRunner

from mbgw.cli import main
from mbgw.ops.control import ControlServer
from mbgw.table.control import table_commands
from mbgw.table.memory import Table


@pytest.fixture
def table() -> Table:
    return Table()


@pytest.fixture
def commands(table):
    return table_commands(table)


def test_read_registers(table, commands):
    table.write(0x1000, [0x1234, 0xFFFF, 0])
    reply = commands["table-read"]({"command": "table-read", "address": 0x1000, "count": 3})
    assert reply == {"address": 0x1000, "bits": False, "values": [0x1234, 0xFFFF, 0]}
    assert commands["table-read"]({"address": 0x1000})["values"] == [0x1234]   # count 1


def test_read_bits_is_bit_b_mod_16_of_register_b_div_16(table, commands):
    table.write(0x0001, [0b1000_0000_0000_0101])
    reply = commands["table-read"]({"address": 16, "count": 16, "bits": True})
    assert reply["values"] == [1, 0, 1] + [0] * 12 + [1]


def test_read_the_configuration_zone_is_allowed(commands):
    assert len(commands["table-read"]({"address": 0xFFF0, "count": 16})["values"]) == 16


def test_write_registers_and_log_the_uid(table, commands, caplog):
    with caplog.at_level(logging.INFO, logger="mbgw.table"):
        reply = commands["table-write"]({"address": 0x0800, "values": [1, 2, 65535],
                                         "uid": 1000})
    assert reply == {"ok": True, "address": 0x0800, "count": 3}
    assert table.read(0x0800, 3) == [1, 2, 65535]
    assert [r.levelname for r in caplog.records] == ["INFO"]
    assert "0x0800..0x0802" in caplog.text and "uid 1000" in caplog.text


@pytest.mark.parametrize("request_, reason", [
    ({}, "'address' missing"),
    ({"address": "4096"}, "address '4096' is not an integer"),
    ({"address": True}, "address True is not an integer"),
    ({"address": 65536}, "register address 65536: out of range 0..65535"),
    ({"address": -1}, "out of range 0..65535"),
    ({"address": 0, "count": 0}, "count 0: out of range 1..2000"),
    ({"address": 0, "count": 2001}, "count 2001: out of range 1..2000"),
    ({"address": 65535, "count": 2}, "registers 65535..65536 run past the last one"),
    ({"address": 65535, "count": 2, "bits": True}, "bits 65535..65536 run past"),
    ({"address": 0, "bits": "yes"}, "bits 'yes' is not true or false"),
])
def test_bad_reads_are_answered_with_the_reason(commands, request_, reason):
    reply = commands["table-read"](request_)
    assert list(reply) == ["error"] and reason in reply["error"], reply


@pytest.mark.parametrize("request_, reason", [
    ({"values": [1]}, "'address' missing"),
    ({"address": 0x1000}, "'values' must be a list"),
    ({"address": 0x1000, "values": []}, "'values' must be a list of one or more"),
    ({"address": 0x1000, "values": 5}, "'values' must be a list"),
    ({"address": 0x1000, "values": [1, "2"]}, "value '2' for register 4097 is not an integer"),
    ({"address": 0x1000, "values": [1.5]}, "value 1.5 for register 4096 is not an integer"),
    ({"address": 0x1000, "values": [65536]}, "value 65536 for register 4096 (0x1000): out of "
                                             "range 0..65535"),
    ({"address": 0x1000, "values": [-1]}, "out of range 0..65535"),
    ({"address": 0x8000, "values": [1]}, "register 0x8000 is in the configuration zone"),
    ({"address": 0x7FFF, "values": [1, 2]}, "register 0x8000 is in the configuration zone"),
    ({"address": 0xFFFF, "values": [1, 2]}, "run past the last one"),
])
def test_bad_writes_are_answered_with_the_reason_and_write_nothing(table, commands, request_,
                                                                   reason):
    before = table.read(0x0FF0, 16), table.read(0x7FF0, 16)
    reply = commands["table-write"](request_)
    assert list(reply) == ["error"] and reason in reply["error"], reply
    assert (table.read(0x0FF0, 16), table.read(0x7FF0, 16)) == before


# --- mbgw table read|write against a control socket ------------------------------------------

@pytest.fixture
def socket_path(tmp_path, table):
    """A control server answering the table commands (and nothing else), as a daemon with
    --table does."""
    path = str(tmp_path / "mbgw.sock")
    ready = threading.Event()
    loop = asyncio.new_event_loop()
    server = ControlServer(path, table_commands(table))

    def serve():
        asyncio.set_event_loop(loop)
        loop.run_until_complete(server.start())
        ready.set()
        loop.run_forever()
    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    ready.wait(10)
    yield path
    loop.call_soon_threadsafe(loop.stop)
    thread.join(10)
    server.close()
    loop.close()


def mbgw(*args):
    return CliRunner().invoke(main, [str(a) for a in args], prog_name="mbgw")


def test_cli_write_then_read(table, socket_path):
    result = mbgw("table", "write", "0x1000", "4660", "0xFFFF", "--control", socket_path)
    assert result.exit_code == 0, result.output
    assert result.output == "registers 0x1000..0x1001 written\n"
    assert table.read(0x1000, 2) == [0x1234, 0xFFFF]
    result = mbgw("table", "read", "4096", "3", "--control", socket_path)
    assert result.exit_code == 0, result.output
    assert result.output == ("0x1000   4660  0x1234\n"
                             "0x1001  65535  0xFFFF\n"
                             "0x1002      0  0x0000\n")
    result = mbgw("table", "write", "0x0800", "1", "--control", socket_path)
    assert result.output == "register 0x0800 written\n"


def test_cli_read_bits_and_json(table, socket_path):
    table.write(0x0002, [0b0110])                  # bits 33 and 34
    result = mbgw("table", "read", "32", "4", "--bits", "--control", socket_path)
    assert result.exit_code == 0, result.output
    assert result.output == "0x0020  0\n0x0021  1\n0x0022  1\n0x0023  0\n"
    result = mbgw("table", "read", "0x0002", "--json", "--control", socket_path)
    assert json.loads(result.output) == {"address": 2, "bits": False, "values": [6]}


@pytest.mark.parametrize("args, reason", [
    (("write", "0x8000", "1"), "register 0x8000 is in the configuration zone"),
    (("read", "0xFFFF", "2"), "run past the last one"),
])
def test_cli_daemon_refusals_are_failures(socket_path, args, reason):
    result = mbgw("table", *args, "--control", socket_path)
    assert result.exit_code == 1 and reason in result.output, result.output


@pytest.mark.parametrize("args, reason", [
    (("read", "0x10000"), "0x10000 is out of range 0..65535"),
    (("read", "ten"), "'ten' is not a number"),
    (("read", "0", "0"), "0 is not in the range"),
    (("write", "0x1000", "65536"), "65536 is out of range 0..65535"),
    (("write", "0x1000"), "Missing argument 'VALUE...'"),
])
def test_cli_bad_arguments_are_usage_errors(args, reason):
    result = mbgw("table", *args, "--control", "/nonexistent/mbgw.sock")
    assert result.exit_code == 2 and reason in result.output, result.output


def test_cli_says_when_the_daemon_has_no_table(tmp_path):
    path = str(tmp_path / "mbgw.sock")
    loop = asyncio.new_event_loop()
    server = ControlServer(path, {})
    loop.run_until_complete(server.start())
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    try:
        result = mbgw("table", "read", "0", "--control", path)
    finally:
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10)
        server.close()
        loop.close()
    assert result.exit_code == 1
    assert "the daemon serves no exchange table (start it with --table" in result.output


def test_cli_without_a_daemon_names_the_socket():
    result = mbgw("table", "read", "0", "--control", "/nonexistent/mbgw.sock")
    assert result.exit_code == 1 and "no mbgw daemon answers on /nonexistent/mbgw.sock" \
        in result.output
