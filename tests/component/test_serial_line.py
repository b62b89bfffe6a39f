"""The serial line end to end (issue 3): ASCII framing, nocheck, silence, echo suppression and
odd baud rates, through the real gateway on a socat pty pair.

Peers: pymodbus's ASCII and RTU servers (tests/peers/pymodbus_ascii_slave.py,
pymodbus_slave.py: holding register n holds 100 + n) and a scripted slave that shapes its
replies on the wire (tests/peers/paced_slave.py: holding register n holds 1000 + n; what each
address does is listed there).  The clients are pymodbus, mbpoll and raw sockets with MBAP
frames built by tests/modbus.py, so the assertions are on exact bytes.  Readiness is an event
(READY lines, sd_notify); "no reply" is made an event too: with --exception the gateway
answers 0x0B.
"""
import fcntl
import functools
import os
import re
import select
import socket
import struct
import subprocess
import sys
import termios
import time

import pytest
from pymodbus.client import ModbusTcpClient

from mbgw.config.model import Interface, SerialConfig
from mbgw.errors import LineTimeout
from mbgw.line.serial_line import SerialLine
from mbgw.ops.counters import Counters
from mbgw.ops.device_stats import DeviceHealth
from mbgw.slave.framing import framing_for
from mbgw.slave.transaction import SerialMaster
from tests.harness import READY_TIMEOUT_S, stop_counters
from tests.modbus import holding_reply, mbap, read_holding, rtu
from tests.peers import paced_slave

pytestmark = pytest.mark.integration

REPLY_S = 5.0               # a reply that is due never takes this long
STOUT_MS = 300
VENDOR_FC = 0x41            # paced_slave's function whose reply length only silence can tell
VENDOR_DATA = bytes(range(0xA0, 0xA0 + 20))
TARGET_FAILED = 0x0B


# --- fixtures ---------------------------------------------------------------------------------

@pytest.fixture
def gateway(pty_pair, start_gateway, tmp_path):
    """gateway(*options) -> a ready gateway on the pty pair (19200 bit/s unless given).

    The harness closes its NOTIFY_SOCKET once READY=1 has come, and the gateway's STOPPING=1
    would then fail before it logs its counters: listen again on that path."""
    listeners = []

    def start(*options: str):
        if "--baudrate" not in options:
            options = ("--baudrate", "19200", *options)
        gw = start_gateway(pty_pair.gateway, *options)
        path = tmp_path / f"notify-{gw.port}"
        path.unlink()
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        listener.bind(str(path))
        listeners.append(listener)
        return gw

    yield start
    for listener in listeners:
        listener.close()


@pytest.fixture
def paced(recording_peer):
    """paced(*options) -> the path of paced_slave's record of what it received."""
    return functools.partial(recording_peer, "paced_slave.py")


@pytest.fixture
def client(client):
    """conftest's client, with this module's REPLY_S."""
    return functools.partial(client, timeout=REPLY_S)


def recorded(record) -> list[bytes]:
    return [bytes.fromhex(line.split(" ", 1)[1]) for line in record.read_text().splitlines()]


# --- ASCII against pymodbus's ASCII server ------------------------------------------------------

@pytest.fixture
def ascii_pymodbus(pty_pair, start_peer, gateway):
    start_peer("pymodbus_ascii_slave.py", pty_pair.device, "17")
    return gateway("--protocol", "ascii")


def test_ascii_reads_and_writes_through_pymodbus(ascii_pymodbus):
    gw = ascii_pymodbus
    c = ModbusTcpClient("127.0.0.1", port=gw.port, timeout=REPLY_S, retries=0)
    assert c.connect()
    try:
        assert c.read_holding_registers(0, count=3, device_id=17).registers == [100, 101, 102]
        assert c.read_input_registers(7, count=2, device_id=17).registers == [1007, 1008]
        assert c.read_coils(0, count=4, device_id=17).bits[:4] == [True, False, True, False]
        assert not c.write_register(5, 4242, device_id=17).isError()
        assert c.read_holding_registers(5, count=1, device_id=17).registers == [4242]
        assert not c.write_registers(40, [7, 8, 9], device_id=17).isError()
        assert c.read_holding_registers(40, count=3, device_id=17).registers == [7, 8, 9]
        # a register past the datastore: pymodbus's exception passes through
        assert c.read_holding_registers(200, count=1, device_id=17).exception_code == 2
    finally:
        c.close()
    assert re.search(r"serial \S+ 19200 8n1 ascii rs232", gw.log())
    counters = stop_counters(gw)
    assert counters["crc_errors"] == counters["invalid_frames"] == counters["timeouts"] == 0


def test_ascii_with_mbpoll(ascii_pymodbus):
    out = subprocess.run(["mbpoll", "-m", "tcp", "-a", "17", "-p", str(ascii_pymodbus.port),
                          "-0", "-t", "4", "-r", "10", "-c", "3", "-1", "127.0.0.1"],
                         capture_output=True, text=True, timeout=30)
    assert out.returncode == 0, out.stdout + out.stderr
    values = re.findall(r"^\[(\d+)\]:\s+(\d+)$", out.stdout, re.M)
    assert values == [("10", "110"), ("11", "111"), ("12", "112")], out.stdout


# --- ASCII against the scripted slave -------------------------------------------------------

def test_ascii_request_goes_out_upper_case_with_its_lrc(paced, gateway, client):
    record = paced("--ascii")
    gw = gateway("--protocol", "ascii")
    # address 17 (0x11) answers normally; the request is the spec's own example frame
    assert client(gw).ask(0x11, read_holding(0x6B, 3)) == holding_reply(0x6B, 3)
    assert recorded(record) == [b":1103006B00037E\r\n"]     # Serial Line V1.02 2.5.2.2


def test_ascii_reply_with_a_bad_lrc_is_dropped(paced, gateway, client):
    paced("--ascii")
    gw = gateway("--protocol", "ascii", "--exception", "--stout", str(STOUT_MS))
    c = client(gw)
    assert c.ask(2, read_holding(0, 2)) == bytes((0x83, TARGET_FAILED))
    assert c.ask(1, read_holding(0, 2)) == holding_reply(0, 2)     # the line still works
    counters = stop_counters(gw)
    assert (counters["crc_errors"], counters["timeouts"]) == (1, 1)


def test_ascii_reply_in_lower_case_is_accepted(paced, gateway, client):
    paced("--ascii")
    gw = gateway("--protocol", "ascii", "--exception")
    assert client(gw).ask(3, read_holding(0x10, 4)) == holding_reply(0x10, 4)
    assert stop_counters(gw)["crc_errors"] == 0


def test_ascii_colon_inside_a_frame_restarts_it(paced, gateway, client):
    paced("--ascii")
    gw = gateway("--protocol", "ascii", "--exception")
    assert client(gw).ask(4, read_holding(0, 3)) == holding_reply(0, 3)
    counters = stop_counters(gw)
    assert (counters["crc_errors"], counters["timeouts"]) == (0, 0)


@pytest.mark.parametrize("address", [
    7,      # a 605-character frame, then the reply in the same write
    10,     # a 515-character frame, then the reply in the same write
])
def test_ascii_frame_over_513_characters_is_dropped(paced, gateway, client, address):
    paced("--ascii")
    gw = gateway("--protocol", "ascii", "--exception")
    # the peer sends a frame too long, then the reply: only the reply gets through
    assert client(gw).ask(address, read_holding(0, 1)) == holding_reply(0, 1)
    counters = stop_counters(gw)
    assert (counters["invalid_frames"], counters["timeouts"]) == (1, 0)


def test_ascii_frame_from_another_address_is_skipped(paced, gateway, client):
    paced("--ascii")        # address 9: the foreign frame, 10 ms, then the reply
    gw = gateway("--protocol", "ascii", "--exception")
    assert client(gw).ask(9, read_holding(2, 2)) == holding_reply(2, 2)
    assert stop_counters(gw)["wrong_unit"] == 1


def test_ascii_reply_right_behind_a_frame_from_another_address_is_delivered(paced, gateway,
                                                                            client):
    paced("--ascii")        # address 8: the foreign frame and the reply in one write
    gw = gateway("--protocol", "ascii", "--exception")
    assert client(gw).ask(8, read_holding(2, 2)) == holding_reply(2, 2)
    assert stop_counters(gw)["wrong_unit"] == 1


def test_ascii_noise_before_the_reply_is_skipped_and_counted(paced, gateway, client):
    paced("--ascii")        # address 11: noise, a frame cut short, then the reply (one write)
    gw = gateway("--protocol", "ascii", "--exception")
    assert client(gw).ask(11, read_holding(0, 2)) == holding_reply(0, 2)
    counters = stop_counters(gw)
    reply = paced_slave.ascii_frame(bytes((11,)) + holding_reply(0, 2))
    noise = len(paced_slave.ASCII_NOISE)
    assert (counters["noise_bytes"], counters["bytes_received"]) == (noise, noise + len(reply))
    assert (counters["invalid_frames"], counters["crc_errors"]) == (0, 0)


@pytest.mark.serial
def test_ascii_pause_inside_a_frame_under_the_ascii_timeout_is_allowed(paced, gateway, client):
    paced("--ascii", "--gap-ms", "300")
    gw = gateway("--protocol", "ascii", "--exception")      # 1 s inter-character, 600 ms stout
    assert client(gw).ask(5, read_holding(0, 2)) == holding_reply(0, 2)


@pytest.mark.serial
def test_ascii_pause_over_the_ascii_timeout_breaks_the_frame(paced, gateway, client):
    paced("--ascii", "--gap-ms", "300")
    gw = gateway("--protocol", "ascii", "--exception", "--ascii-timeout", "100")
    c = client(gw)
    assert c.ask(5, read_holding(0, 2)) == bytes((0x83, TARGET_FAILED))
    assert c.ask(1, read_holding(0, 2)) == holding_reply(0, 2)
    counters = stop_counters(gw)
    assert (counters["invalid_frames"], counters["timeouts"]) == (1, 1)


# --- nocheck -------------------------------------------------------------------------------

def test_nocheck_forwards_a_reply_with_a_wrong_crc_as_sent(paced, gateway, client):
    paced()
    gw = gateway("--nocheck")
    assert client(gw).ask(4, read_holding(3, 2)) == holding_reply(3, 2)
    assert "nocheck is on" in gw.log() and "WARNING" in gw.log()
    assert stop_counters(gw)["crc_errors"] == 0


def test_without_nocheck_a_reply_with_a_wrong_crc_is_dropped_and_counted(paced, gateway,
                                                                        client):
    paced()
    gw = gateway("--exception", "--stout", str(STOUT_MS))
    c = client(gw)
    assert c.ask(4, read_holding(3, 2)) == bytes((0x83, TARGET_FAILED))
    assert c.ask(1, read_holding(3, 2)) == holding_reply(3, 2)
    assert "nocheck is on" not in gw.log()
    counters = stop_counters(gw)
    assert (counters["crc_errors"], counters["timeouts"]) == (1, 1)


def test_nocheck_forwards_a_reply_from_another_address(paced, gateway, client):
    paced()
    gw = gateway("--nocheck")
    assert client(gw).ask(5, read_holding(0, 1)) == holding_reply(0, 1)


def test_nocheck_forwards_a_reply_of_the_wrong_length_whole(paced, gateway, client):
    paced()
    gw = gateway("--nocheck")
    assert client(gw).ask(6, read_holding(0, 2)) == holding_reply(0, 2) + b"\xEE\xEE"


def test_without_nocheck_a_reply_of_the_wrong_length_is_dropped(paced, gateway, client):
    paced()
    gw = gateway("--exception", "--stout", str(STOUT_MS))
    assert client(gw).ask(6, read_holding(0, 2)) == bytes((0x83, TARGET_FAILED))


def test_nocheck_forwards_a_vendor_reply_with_a_wrong_crc(paced, gateway, client):
    paced()
    gw = gateway("--nocheck")
    assert client(gw).ask(4, bytes((VENDOR_FC, 1, 2))) == bytes((VENDOR_FC,)) + VENDOR_DATA


def test_nocheck_never_sends_a_reply_without_a_function_code(paced, gateway, client):
    paced()
    gw = gateway("--nocheck", "--exception", "--stout", str(STOUT_MS))
    # address 8 sends its address and function code only: after the CRC and the address
    # are cut there is no PDU left, and an MBAP frame without a function code is no reply
    assert client(gw).ask(8, read_holding(0, 1)) == bytes((0x83, TARGET_FAILED))


def test_nocheck_in_ascii_forwards_a_reply_with_a_wrong_lrc(paced, gateway, client):
    paced("--ascii")
    gw = gateway("--protocol", "ascii", "--nocheck")
    assert client(gw).ask(2, read_holding(0, 2)) == holding_reply(0, 2)


# --- silence ---------------------------------------------------------------------------------

SILENCE_CASES = [
    pytest.param(read_holding(4, 3), holding_reply(4, 3), id="fc03-framed-by-libmodbus"),
    pytest.param(bytes((VENDOR_FC, 1, 2)), bytes((VENDOR_FC,)) + VENDOR_DATA,
                 id="fc41-framed-by-silence"),
]


@pytest.mark.serial
@pytest.mark.parametrize("request_pdu, reply_pdu", SILENCE_CASES)
def test_gap_shorter_than_silence_stays_inside_the_frame(paced, gateway, client, request_pdu,
                                                         reply_pdu):
    paced("--gap-ms", "10")
    gw = gateway("--silence", "20", "--exception")
    assert client(gw).ask(2, request_pdu) == reply_pdu
    counters = stop_counters(gw)
    assert (counters["crc_errors"], counters["invalid_frames"], counters["timeouts"]) == (0, 0, 0)


@pytest.mark.serial
@pytest.mark.parametrize("request_pdu, reply_pdu", SILENCE_CASES)
def test_gap_longer_than_t35_ends_the_frame(paced, gateway, client, request_pdu, reply_pdu):
    paced("--gap-ms", "10")
    gw = gateway("--exception", "--stout", str(STOUT_MS))      # 19200 bit/s: t3.5 = 1.82 ms
    # no second request here: the reply's second half is still on its way after the gateway
    # has given up, and a request sent now would collide with it on the line
    assert client(gw).ask(2, request_pdu) == bytes((request_pdu[0] | 0x80, TARGET_FAILED))
    assert stop_counters(gw)["timeouts"] == 1


# --- echo ----------------------------------------------------------------------------------

def test_rs485_on_a_tty_without_rts_still_works(paced, gateway, client):
    paced()
    gw = gateway("--interface", "rs485", "--exception")
    assert client(gw).ask(1, read_holding(0, 2)) == holding_reply(0, 2)


@pytest.mark.parametrize("protocol, address", [("rtu", 3), ("ascii", 6)])
def test_echo_mode_gives_the_right_answer(paced, gateway, client, protocol, address):
    paced(*(["--ascii"] if protocol == "ascii" else []))
    gw = gateway("--protocol", protocol, "--interface", "rs485 echo", "--exception")
    c = client(gw)
    assert c.ask(address, read_holding(5, 2)) == holding_reply(5, 2)
    assert c.ask(address, struct.pack(">BHH", 6, 9, 0x1234)) == struct.pack(">BHH", 6, 9, 0x1234)
    counters = stop_counters(gw)
    assert (counters["crc_errors"], counters["invalid_frames"], counters["timeouts"]) == (0, 0, 0)


@pytest.fixture
def in_process(pty_pair):
    """in_process(protocol, interface) -> a SerialMaster on the gateway's end of the pty, run in
    this process.  RTS control is switched off by hand: a pty has no RTS,
    and this exercises echo suppression alone."""
    lines = []

    def make(protocol: str = "rtu", interface: str = "rs485 echo", stout_ms: int = STOUT_MS):
        cfg = SerialConfig(pty_pair.gateway, baudrate=19200, protocol=protocol,
                           interface=Interface.parse(interface), stout_ms=stout_ms)
        counters = Counters()
        line = SerialLine(cfg, counters)
        lines.append(line)
        line.rts_control = False
        return SerialMaster(framing_for(line), cfg, counters, DeviceHealth()), counters

    yield make
    for line in lines:
        line.close()


@pytest.mark.parametrize("protocol, address", [("rtu", 3), ("ascii", 6)])
def test_echo_is_discarded_before_the_reply_in_process(paced, in_process, protocol, address):
    paced(*(["--ascii"] if protocol == "ascii" else []))
    master, counters = in_process(protocol)
    request = bytes((address,)) + read_holding(5, 2)
    assert master.transact(request) == holding_reply(5, 2)
    write = bytes((address,)) + struct.pack(">BHH", 6, 9, 0x1234)
    assert master.transact(write) == write[1:]
    assert (counters.crc_errors, counters.invalid_frames, counters.wrong_unit) == (0, 0, 0)


def test_echo_collision_is_no_valid_reply(paced, in_process):
    paced()
    master, counters = in_process("rtu")
    with pytest.raises(LineTimeout):
        master.transact(bytes((7,)) + read_holding(0, 1))
    assert counters.echo_errors == 1


def test_echo_mode_without_an_echo_times_out(paced, in_process):
    paced()                     # address 1 answers without echoing
    master, counters = in_process("rtu")
    with pytest.raises(LineTimeout):
        master.transact(bytes((1,)) + read_holding(0, 1))
    assert counters.echo_errors == 1


def test_echo_not_configured_is_never_taken_for_a_reply(paced, gateway, client):
    """The echo of an FC 03 request is a frame from the same address with the same function.
    Without 'rs485 echo' it must not reach the client as the answer: read as a reply,
    03 03 00 .. has byte count 0 and a wrong CRC, so it is noise, and the real reply right
    behind it is found and delivered."""
    paced()
    gw = gateway("--exception", "--stout", str(STOUT_MS))
    c = client(gw)
    assert c.ask(3, read_holding(0, 2)) == holding_reply(0, 2)
    assert c.ask(1, read_holding(0, 2)) == holding_reply(0, 2)
    counters = stop_counters(gw)
    echo = rtu(3, read_holding(0, 2))
    assert (counters["crc_errors"], counters["noise_bytes"]) == (0, len(echo))


@pytest.mark.serial
def test_echo_not_configured_fc06_echo_is_taken_as_the_reply(paced, gateway, client):
    """The echo of an FC 06 request is byte for byte a valid FC 06 reply: the gateway cannot
    tell them apart and answers with it (the right bytes by construction); the real reply
    that follows is skipped as late bytes before the next request."""
    paced()
    gw = gateway("--exception", "--stout", str(STOUT_MS))
    c = client(gw)
    write = struct.pack(">BHH", 6, 9, 0x1234)
    assert c.ask(3, write) == write
    assert c.ask(1, read_holding(0, 2)) == holding_reply(0, 2)
    counters = stop_counters(gw)
    # skipped before the next request, or while the line was idle
    assert counters["late_bytes"] + counters["unsolicited_bytes"] == 8


@pytest.mark.serial
def test_ascii_echo_not_configured_is_skipped_as_a_wrong_reply(paced, gateway, client):
    """In ASCII the echo of an FC 03 request decodes as a reply whose byte count does not
    match the request: it is dropped (wrong_function) and the real reply behind it, a frame
    of its own after CR LF, is delivered."""
    paced("--ascii", "--gap-ms", "10")     # address 6: the echo, 10 ms, the reply
    gw = gateway("--protocol", "ascii", "--exception")
    assert client(gw).ask(6, read_holding(0, 2)) == holding_reply(0, 2)
    counters = stop_counters(gw)
    assert (counters["wrong_function"], counters["timeouts"]) == (1, 0)


# --- baud rate outside libmodbus's table ---------------------------------------------------

TERMIOS2 = struct.Struct("=4I B 19s I I")     # struct termios2, asm-generic/termbits.h
TCGETS2 = (2 << 30) | (TERMIOS2.size << 16) | (ord("T") << 8) | 0x2A
CMSPAR = 0o10000000000


def kernel_line(path: str) -> tuple[int, int]:
    """(cflag, output rate) the kernel holds for the tty at path, read from outside the
    gateway (root may open a tty held with TIOCEXCL)."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        fields = TERMIOS2.unpack(fcntl.ioctl(fd, TCGETS2, bytes(TERMIOS2.size)))
    finally:
        os.close(fd)
    assert fields[-2] == fields[-1], "input and output rates differ"
    return fields[2], fields[-1]


def test_baudrate_7200_end_to_end(pty_pair, start_peer, gateway):
    start_peer("pymodbus_slave.py", pty_pair.device, "17")
    gw = gateway("--baudrate", "7200")
    c = ModbusTcpClient("127.0.0.1", port=gw.port, timeout=REPLY_S, retries=0)
    assert c.connect()
    try:
        assert c.read_holding_registers(0, count=3, device_id=17).registers == [100, 101, 102]
        assert not c.write_register(3, 777, device_id=17).isError()
        assert c.read_holding_registers(3, count=1, device_id=17).registers == [777]
    finally:
        c.close()
    assert re.search(r"serial \S+ 7200 8n1 rtu", gw.log()), gw.log()
    assert kernel_line(pty_pair.gateway)[1] == 7200


@pytest.mark.parametrize("fmt, bits", [
    # a pty forces CS8 and clears PARENB; PARODD, CMSPAR and CSTOPB are what it keeps
    ("8m1", termios.PARODD | CMSPAR),
    ("8s2", CMSPAR | termios.CSTOPB),
    ("8o2", termios.PARODD | termios.CSTOPB),
    ("7m1", termios.PARODD | CMSPAR),
])
def test_line_format_reaches_the_kernel(pty_pair, start_peer, gateway, client, fmt, bits):
    start_peer("pymodbus_slave.py", pty_pair.device, "17")
    gw = gateway("--format", fmt, "--baudrate", "14400")
    assert client(gw).ask(17, read_holding(0, 1)) == bytes((0x03, 2, 0, 100))
    cflag, rate = kernel_line(pty_pair.gateway)
    assert cflag & (termios.PARODD | CMSPAR | termios.CSTOPB) == bits, oct(cflag)
    assert rate == 14400
    assert re.search(rf"serial \S+ 14400 {fmt} rtu", gw.log()), gw.log()


def _second_gateway(device: str, *options: str) -> subprocess.CompletedProcess:
    from tests.harness import free_port
    return subprocess.run([sys.executable, "-m", "mbgw", "slave", "--device", device,
                           "--bind", "127.0.0.1", "--mdbport", str(free_port()), *options],
                          capture_output=True, text=True, timeout=READY_TIMEOUT_S,
                          env={**os.environ, "MBGW_CONFIG": os.devnull})


def test_second_gateway_on_the_same_line_fails_clearly(pty_pair, start_peer, gateway, client):
    start_peer("pymodbus_slave.py", pty_pair.device, "17")
    gw = gateway()
    second = _second_gateway(pty_pair.gateway)
    assert second.returncode == 1, second.stdout + second.stderr
    assert "in use" in second.stderr, second.stderr
    assert client(gw).ask(17, read_holding(1, 1)) == bytes((0x03, 2, 0, 101))   # untouched


def test_second_gateway_leaves_the_first_ones_rate_alone(pty_pair, start_peer, gateway):
    start_peer("pymodbus_slave.py", pty_pair.device, "17")
    gateway("--baudrate", "7200")
    assert _second_gateway(pty_pair.gateway, "--baudrate", "9600").returncode == 1
    assert kernel_line(pty_pair.gateway)[1] == 7200


# --- RS-232 control lines and flow control (the guide's dtr, rts, cts, xonxoff) --------------
# A pty has termios but no modem lines (TIOCMGET/TIOCMBIS: ENOTTY): the flow control flags are
# read back from the kernel and XON/XOFF is seen at work on the wire; DTR and RTS levels can
# only be seen refused, and said so in the log.

def kernel_flags(path: str) -> tuple[int, int]:
    """(iflag, cflag) the kernel holds for the tty at path."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        fields = TERMIOS2.unpack(fcntl.ioctl(fd, TCGETS2, bytes(TERMIOS2.size)))
    finally:
        os.close(fd)
    return fields[0], fields[2]


def test_rts_cts_flow_control_reaches_the_kernel(pty_pair, start_peer, gateway, client):
    start_peer("pymodbus_slave.py", pty_pair.device, "17")
    gw = gateway("--rts", "flow", "--cts", "flow")
    assert client(gw).ask(17, read_holding(0, 1)) == bytes((0x03, 2, 0, 100))
    iflag, cflag = kernel_flags(pty_pair.gateway)
    assert cflag & termios.CRTSCTS, oct(cflag)
    assert not iflag & (termios.IXON | termios.IXOFF), oct(iflag)
    assert "rs232, rts flow, cts flow" in gw.log()


def test_without_flow_control_the_kernel_has_none(pty_pair, start_peer, gateway, client):
    start_peer("pymodbus_slave.py", pty_pair.device, "17")
    gw = gateway()
    assert client(gw).ask(17, read_holding(0, 1)) == bytes((0x03, 2, 0, 100))
    iflag, cflag = kernel_flags(pty_pair.gateway)
    assert not cflag & termios.CRTSCTS and not iflag & (termios.IXON | termios.IXOFF)


def test_rts_flow_without_cts_flow_is_refused_naming_both(pty_pair):
    out = _second_gateway(pty_pair.gateway, "--rts", "flow")
    assert out.returncode == 2, out.stdout + out.stderr
    assert "rts flow with cts ignore" in out.stderr and "--rts" in out.stderr, out.stderr


def test_rts_modem_is_refused_on_rs485(pty_pair):
    out = _second_gateway(pty_pair.gateway, "--interface", "2wires", "--rts", "modem")
    assert out.returncode == 2, out.stdout + out.stderr
    assert "interface rs485 drives its transmitter with RTS" in out.stderr, out.stderr


def _line_end(path: str) -> int:
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    termios.tcsetattr(fd, termios.TCSANOW, _raw(termios.tcgetattr(fd)))
    return fd


def _raw(attrs: list) -> list:
    attrs[0] = attrs[1] = attrs[3] = 0
    return attrs


def _serve_one(fd: int, reply: bytes) -> bytes:
    """Read one 8-byte RTU request from the line, answer with reply; the request."""
    request = b""
    while len(request) < 8:
        ready, _, _ = select.select([fd], [], [], REPLY_S)
        assert ready, f"no request on the line, got {request.hex(' ')!r}"
        request += os.read(fd, 8 - len(request))
    os.write(fd, reply)
    return request


@pytest.mark.parametrize("xonxoff, answered", [("use", True), ("ignore", False)])
def test_xonxoff_takes_an_xon_out_of_the_reply(pty_pair, gateway, client, xonxoff, answered):
    """A modem's XON inside the reply: with xonxoff use the kernel takes it out of the line
    and the reply is whole; without, it is a byte of the frame and spoils its CRC."""
    fd = _line_end(pty_pair.device)
    try:
        gw = gateway("--xonxoff", xonxoff, "--exception", "--stout", str(STOUT_MS))
        iflag, _ = kernel_flags(pty_pair.gateway)
        assert bool(iflag & termios.IXON) == answered and bool(iflag & termios.IXOFF) == answered
        c = client(gw)
        c.send(struct.pack(">HHHB", 1, 0, 6, 1) + read_holding(0, 1))
        reply = rtu(1, bytes((0x03, 2, 0x12, 0x34)))
        request = _serve_one(fd, reply[:3] + b"\x11" + reply[3:])
        assert request == rtu(1, read_holding(0, 1))
        expected = bytes((0x03, 2, 0x12, 0x34)) if answered else bytes((0x83, TARGET_FAILED))
        assert c.recv() == (1, 1, expected)
    finally:
        os.close(fd)


def test_dtr_and_rts_levels_on_a_tty_without_modem_lines_are_reported(pty_pair, start_peer,
                                                                       gateway, client):
    start_peer("pymodbus_slave.py", pty_pair.device, "17")
    gw = gateway("--dtr", "low", "--rts", "low")
    assert client(gw).ask(17, read_holding(0, 1)) == bytes((0x03, 2, 0, 100))
    assert f"{pty_pair.gateway} has no modem control lines: dtr low, rts low not applied" \
        in gw.log(), gw.log()


def test_rts_modem_on_a_tty_without_rts_says_the_radio_cannot_be_keyed(pty_pair, start_peer,
                                                                        gateway, client):
    start_peer("pymodbus_slave.py", pty_pair.device, "17")
    gw = gateway("--rts", "modem", "--rtsdelays", "2", "1")
    assert client(gw).ask(17, read_holding(0, 1)) == bytes((0x03, 2, 0, 100))
    assert f"{pty_pair.gateway} has no RTS line: rts modem cannot key the radio" in gw.log()


def test_default_lines_log_no_modem_warning(pty_pair, start_peer, gateway, client):
    start_peer("pymodbus_slave.py", pty_pair.device, "17")
    gw = gateway()
    assert client(gw).ask(17, read_holding(0, 1)) == bytes((0x03, 2, 0, 100))
    assert "modem control lines" not in gw.log()


@pytest.mark.parametrize("words, shown", [("4wires slave", "rs422 slave"),
                                          ("rs422 master", "rs422")])
def test_the_guides_4wires_words_run_the_line(pty_pair, start_peer, gateway, client, words,
                                              shown):
    start_peer("pymodbus_slave.py", pty_pair.device, "17")
    gw = gateway("--interface", words)
    assert client(gw).ask(17, read_holding(0, 1)) == bytes((0x03, 2, 0, 100))
    assert f"8n1 rtu {shown}," in gw.log(), gw.log()


def test_the_guides_2wires_echo_drops_the_echo(paced, gateway, client):
    paced()
    gw = gateway("--interface", "2wires echo", "--exception")
    assert client(gw).ask(3, read_holding(0, 2)) == holding_reply(0, 2)   # echo, then reply
    assert "8n1 rtu rs485 echo," in gw.log(), gw.log()


# --- VPGate's interframe silence (slave mode) -------------------------------------------------

INTERFRAME_MS = 300


def test_the_interframe_silence_holds_the_next_request_after_a_reply(pty_pair, gateway, client):
    """The next request goes out no sooner than the silence after the reply was written (a
    lower bound: load only makes it later)."""
    fd = _line_end(pty_pair.device)
    try:
        gw = gateway("--interframe-silence", str(INTERFRAME_MS))
        c = client(gw)
        c.send(mbap(1, 1, read_holding(0, 1)), mbap(2, 1, read_holding(1, 1)))
        reply = rtu(1, bytes((0x03, 2, 0x12, 0x34)))
        assert _serve_one(fd, reply) == rtu(1, read_holding(0, 1))
        replied = time.monotonic()
        assert _serve_one(fd, reply) == rtu(1, read_holding(1, 1))
        assert time.monotonic() - replied >= INTERFRAME_MS / 1000
        assert [c.recv(), c.recv()] == [(1, 1, bytes((0x03, 2, 0x12, 0x34))),
                                        (2, 1, bytes((0x03, 2, 0x12, 0x34)))]
    finally:
        os.close(fd)
