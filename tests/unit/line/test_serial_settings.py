"""Serial line settings (issue 3): the ASCII codec against published frames, the line format
bits against the kernel's constants, baud rates read back from a real pty, the exclusive claim,
option validation and `mbgw slave --help`.

ptys force CS8 and no parity and keep the baud rate without pacing (notes/libmodbus.md 3.7-3.8):
the format is checked on the cflag the C code builds, the rate on a pty, where the kernel keeps
it.  Expected values come from the Modbus specification, the VPGate manual and the kernel
headers, never from mbgw's own code.
"""
import fcntl
import os
import re
import shutil
import struct
import subprocess
import sys
import termios

import pytest
from click.testing import CliRunner

from mbgw.cli import main
from mbgw.config.model import Interface, LineFormat, SerialConfig
from mbgw.errors import ChecksumError, ConfigError, FrameError, SerialError
from mbgw.line import native
from mbgw.line.serial_line import SerialLine
from tests.harness import CHECKOUT, factory, reachable_by_others

# ---------------------------------------------------------------------------------------------
# ASCII codec
# ---------------------------------------------------------------------------------------------

# (address .. data, LRC, source).  The VPGate ones are in the manual's appendix A, "Format of
# the MODBUS frames" (/work/shared/seeds/001_63fcdfccdc4e7658.txt), column "Bytes sent in case
# of ASCII"; its FC 04 reply is left out: the table lists a byte too many for its LRC.
ASCII_VECTORS = [
    ("11 03 00 6B 00 03", 0x7E, "Modbus over Serial Line V1.02 2.5.2.2 / ':1103006B00037E'"),
    ("11 03 00 00 00 03", 0xE9, "notes/libmodbus.md 2.1, run against pymodbus's ASCII server"),
    ("11 03 06 00 64 00 65 00 66", 0xB7, "notes/libmodbus.md 2.1, pymodbus's ASCII answer"),
    ("39 01 00 22 00 12", 0x92, "VPGate appendix A, function 1 request"),
    ("39 01 03 59 C4 01", 0xA5, "VPGate appendix A, function 1 response"),
    ("39 02 00 22 00 12", 0x91, "VPGate appendix A, function 2 request"),
    ("39 02 03 59 C4 01", 0xA4, "VPGate appendix A, function 2 response"),
    ("39 03 00 22 00 02", 0xA0, "VPGate appendix A, function 3 request"),
    ("39 03 04 68 31 47 59", 0x87, "VPGate appendix A, function 3 response"),
    ("39 04 00 22 00 03", 0x9E, "VPGate appendix A, function 4 request"),
    ("01 05 00 22 FF 00", 0xD9, "VPGate appendix A, function 5 request and response"),
    ("39 06 00 22 00 56", 0x49, "VPGate appendix A, function 6 request and response"),
    ("39 0F 00 22 00 12 03 2B 06 03", 0x4D, "VPGate appendix A, function 15 request"),
    ("39 0F 00 22 00 12", 0x84, "VPGate appendix A, function 15 response"),
]
ASCII_IDS = [v[2] for v in ASCII_VECTORS]


def published(body_hex: str, lrc: int) -> bytes:
    """The frame as the sources print it: ':' upper-case hex pairs, the LRC, CR LF."""
    return b":" + body_hex.replace(" ", "").encode() + f"{lrc:02X}".encode() + b"\r\n"


def test_spec_example_literally():
    assert native.ascii_encode(bytes.fromhex("11 03 00 6B 00 03")) == b":1103006B00037E\r\n"
    assert native.ascii_decode(b":1103006B00037E\r\n") == bytes.fromhex("11 03 00 6B 00 03")


def test_vpgate_examples_literally():
    # Appendix A, function 1: request ":390100220012" LRC "92", response ":39010359C401" "A5"
    assert native.ascii_encode(bytes.fromhex("39 01 00 22 00 12")) == b":39010022001292\r\n"
    assert native.ascii_encode(bytes.fromhex("39 01 03 59 C4 01")) == b":39010359C401A5\r\n"


@pytest.mark.parametrize("body, lrc, source", ASCII_VECTORS, ids=ASCII_IDS)
def test_lrc(body, lrc, source):
    assert native.lrc(bytes.fromhex(body)) == lrc


@pytest.mark.parametrize("body, lrc, source", ASCII_VECTORS, ids=ASCII_IDS)
def test_encode(body, lrc, source):
    assert native.ascii_encode(bytes.fromhex(body)) == published(body, lrc)


@pytest.mark.parametrize("body, lrc, source", ASCII_VECTORS, ids=ASCII_IDS)
def test_decode(body, lrc, source):
    assert native.ascii_decode(published(body, lrc)) == bytes.fromhex(body)


@pytest.mark.parametrize("body, lrc, source", ASCII_VECTORS, ids=ASCII_IDS)
def test_decode_accepts_lower_case_hex(body, lrc, source):
    assert native.ascii_decode(published(body, lrc).lower()) == bytes.fromhex(body)


def test_decode_accepts_mixed_case_hex():
    assert native.ascii_decode(b":39010359c401A5\r\n") == bytes.fromhex("39 01 03 59 C4 01")


@pytest.mark.parametrize("frame", [
    b":1103006B00037F\r\n",      # LRC one off
    b":1103006B00047E\r\n",      # a data byte changed, LRC kept
    b":39010022001293\r\n",
    b":39010359C401A4\r\n",
])
def test_decode_refuses_a_wrong_lrc(frame):
    with pytest.raises(ChecksumError):
        native.ascii_decode(frame)


@pytest.mark.parametrize("frame", [
    b"1103006B00037E\r\n",       # no ':'
    b";1103006B00037E\r\n",      # another start character
    b":1103006B00037E\n",        # no CR
    b":1103006B00037E\r",        # no LF
    b":1103006B00037E\n\r",      # LF CR
    b":1103006B00037E",          # no end at all
    b":1103006B00037\r\n",       # odd number of hex characters
    b":11G3006B00037E\r\n",      # not hex
    b":11 03006B00037E\r\n",     # a space
    b":1103:006B0003\r\n",       # a ':' inside
    b":\r\n",                    # empty
    b":1100\r\n",                # address and LRC only
    b"",
])
def test_decode_refuses_malformed_frames(frame):
    with pytest.raises(FrameError):
        native.ascii_decode(frame)


def _frame_of(n_bytes: int) -> bytes:
    """A well-formed frame (right LRC) of n_bytes address..data bytes: 2 n + 5 characters."""
    body = bytes((0x11, 0x41)) + bytes(i & 0xFF for i in range(n_bytes - 2))
    return b":" + (body + bytes((lrc_of(body),))).hex().upper().encode() + b"\r\n"


def lrc_of(data: bytes) -> int:
    """Serial Line V1.02 2.5.2.2: the two's complement of the 8-bit sum."""
    return -sum(data) & 0xFF


def test_largest_frame_is_513_characters_and_accepted():
    frame = _frame_of(254)
    assert len(frame) == 513
    assert native.ascii_decode(frame) == bytes.fromhex(frame[1:-4].decode())
    assert native.ascii_encode(bytes.fromhex(frame[1:-4].decode())) == frame


@pytest.mark.parametrize("n_bytes", [257, 300])
def test_decode_refuses_frames_over_513_characters(n_bytes):
    frame = _frame_of(n_bytes)
    assert len(frame) > 513
    with pytest.raises(FrameError):
        native.ascii_decode(frame)


@pytest.mark.parametrize("n_bytes", [255, 256])
def test_decode_refuses_a_515_or_517_character_frame(n_bytes):
    frame = _frame_of(n_bytes)
    assert len(frame) == 2 * n_bytes + 5 > 513
    with pytest.raises(FrameError):
        native.ascii_decode(frame)


@pytest.mark.parametrize("n_bytes", [255, 256, 300])
def test_encode_refuses_frames_over_513_characters(n_bytes):
    with pytest.raises(FrameError):
        native.ascii_encode(bytes(n_bytes))


def test_encode_sends_upper_case():
    assert native.ascii_encode(bytes.fromhex("AB CD EF")) == b":ABCDEF" + b"%02X\r\n" % (
        lrc_of(bytes.fromhex("AB CD EF")))


# ---------------------------------------------------------------------------------------------
# Line format: the cflag bits, against the kernel's constants
# ---------------------------------------------------------------------------------------------

CMSPAR = 0o10000000000     # Linux include/uapi/asm-generic/termbits.h (Python's termios lacks it)
BOTHER = 0o010000          # same header
FORMAT_BITS = termios.CSIZE | termios.PARENB | termios.PARODD | termios.CSTOPB | CMSPAR
KEPT = termios.CLOCAL | termios.CREAD | termios.B19200
PARITY_BITS = {
    "n": 0,
    "e": termios.PARENB,
    "o": termios.PARENB | termios.PARODD,
    "m": termios.PARENB | CMSPAR | termios.PARODD,     # mark: the parity bit is always 1
    "s": termios.PARENB | CMSPAR,                      # space: always 0
}
SIZE_BITS = {7: termios.CS7, 8: termios.CS8}
STOP_BITS = {1: 0, 2: termios.CSTOPB}


@pytest.mark.parametrize("stop", [1, 2])
@pytest.mark.parametrize("parity", "neoms")
@pytest.mark.parametrize("bits", [7, 8])
def test_cflag_of_every_format(bits, parity, stop):
    want = SIZE_BITS[bits] | PARITY_BITS[parity] | STOP_BITS[stop]
    # from a clean cflag and from one with every format bit already set: all are rewritten
    for start in (KEPT, KEPT | FORMAT_BITS):
        got = native.tty_cflag(start, bits, parity, stop)
        assert got & FORMAT_BITS == want, (oct(start), oct(got), oct(want))
        assert got & ~FORMAT_BITS == KEPT, "other cflag bits must be kept"


def test_cflag_keeps_unrelated_high_bits():
    start = termios.CLOCAL | termios.CREAD | termios.HUPCL | termios.CRTSCTS | BOTHER
    assert native.tty_cflag(start, 8, "n", 1) == start | termios.CS8


# ---------------------------------------------------------------------------------------------
# A real pty opened through SerialLine
# ---------------------------------------------------------------------------------------------

# struct termios2 (asm-generic/termbits.h): 4 tcflag_t, c_line, c_cc[19], c_ispeed, c_ospeed
TERMIOS2 = struct.Struct("=4I B 19s I I")
TCGETS2 = (2 << 30) | (TERMIOS2.size << 16) | (ord("T") << 8) | 0x2A   # _IOR('T', 0x2A, ...)


def kernel_termios2(line: SerialLine) -> tuple[int, int, int]:
    """(cflag, ispeed, ospeed) the kernel holds for line's fd, through our own TCGETS2."""
    raw = fcntl.ioctl(line.port.fd, TCGETS2, bytes(TERMIOS2.size))
    _, _, cflag, _, _, _, ispeed, ospeed = TERMIOS2.unpack(raw)
    return cflag, ispeed, ospeed


@pytest.fixture
def open_line():
    yield from factory(lambda path, **settings: SerialLine(SerialConfig(path, **settings)),
                       SerialLine.close)


# Python's termios names for the rates libmodbus sets itself
B_CONSTANTS = {110: termios.B110, 9600: termios.B9600, 19200: termios.B19200,
               115200: termios.B115200, 1000000: termios.B1000000}


@pytest.mark.parametrize("baud", [50, 110, 7200, 9600, 14400, 19200, 115200, 250000, 1000000,
                                  2000000, 4000000])
def test_baud_rate_reads_back_exactly(pty, open_line, baud):
    line = open_line(pty, baudrate=baud)
    _, rate = line.port.settings()
    assert rate == baud
    cflag, ispeed, ospeed = kernel_termios2(line)
    assert (ispeed, ospeed) == (baud, baud), "the kernel runs the line at another rate"
    speed = termios.tcgetattr(line.port.fd)[5]
    if speed != BOTHER:     # a rate given through BOTHER has no Bxxx to read back
        assert speed == getattr(termios, f"B{baud}")


@pytest.mark.parametrize("baud", [50, 7200, 14400, 250000])
def test_rate_outside_libmodbus_table_is_never_9600(pty, open_line, baud):
    line = open_line(pty, baudrate=baud)
    cflag, ispeed, ospeed = kernel_termios2(line)
    assert ospeed == baud != 9600
    assert cflag & termios.CBAUD != termios.B9600


@pytest.mark.parametrize("baud", sorted(B_CONSTANTS))
def test_rates_with_a_b_constant_read_back_through_termios(pty, open_line, baud):
    line = open_line(pty, baudrate=baud)
    assert termios.tcgetattr(line.port.fd)[4:6] == [B_CONSTANTS[baud]] * 2


@pytest.mark.parametrize("fmt, present, absent", [
    # ptys force CS8 and clear PARENB; PARODD, CMSPAR and CSTOPB survive and are checked here
    ("8n1", 0, termios.PARODD | CMSPAR | termios.CSTOPB),
    ("8o1", termios.PARODD, CMSPAR | termios.CSTOPB),
    ("8m1", termios.PARODD | CMSPAR, termios.CSTOPB),
    ("8s1", CMSPAR, termios.PARODD | termios.CSTOPB),
    ("8n2", termios.CSTOPB, termios.PARODD | CMSPAR),
    ("7m2", termios.PARODD | CMSPAR | termios.CSTOPB, 0),
    ("7s2", CMSPAR | termios.CSTOPB, termios.PARODD),
])
def test_format_bits_a_pty_keeps(pty, open_line, fmt, present, absent):
    line = open_line(pty, baudrate=19200, format=LineFormat.parse(fmt))
    cflag, _ = line.port.settings()
    assert cflag & present == present, oct(cflag)
    assert cflag & absent == 0, oct(cflag)
    assert kernel_termios2(line)[0] == cflag


TIOCGEXCL = 0x80045440     # Linux include/uapi/asm-generic/ioctls.h: is the tty exclusive?


def _exclusive(path: str) -> bool:
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        return struct.unpack("i", fcntl.ioctl(fd, TIOCGEXCL, b"\0" * 4))[0] != 0
    finally:
        os.close(fd)


def test_line_is_exclusive_while_open_and_released_at_close(pty, open_line):
    """TIOCEXCL outlives our fd while another process holds the tty: a restart of the gateway
    as a non-root user would then be refused."""
    line = open_line(pty, baudrate=19200)
    assert _exclusive(pty)
    line.close()
    assert not _exclusive(pty)


def test_second_open_of_the_same_line_fails_in_use(pty, open_line):
    open_line(pty, baudrate=19200)
    with pytest.raises(SerialError, match="in use"):
        open_line(pty, baudrate=19200)


def test_refused_second_open_leaves_the_first_lines_rate_alone(pty, open_line):
    first = open_line(pty, baudrate=7200)
    with pytest.raises(SerialError, match="in use"):
        open_line(pty, baudrate=9600)
    assert first.port.settings()[1] == 7200
    assert kernel_termios2(first)[2] == 7200


@pytest.mark.skipif(os.geteuid() != 0 or not shutil.which("setpriv"),
                    reason="needs root to run the second open as another user")
def test_second_open_by_another_user_says_in_use(pty, open_line):
    open_line(pty, baudrate=19200)
    os.chmod(pty, 0o666)
    code = ("import sys\n"
            "from mbgw.config.model import SerialConfig\n"
            "from mbgw.line.serial_line import SerialLine\n"
            "try:\n"
            f"    SerialLine(SerialConfig({pty!r}))\n"
            "except Exception as err:\n"
            "    print(type(err).__name__, err)\n")
    with reachable_by_others():
        result = subprocess.run(["setpriv", "--reuid=65534", "--regid=65534",
                                 "--clear-groups", sys.executable, "-c", code],
                                capture_output=True, text=True, timeout=30, cwd=CHECKOUT)
    assert result.stdout.startswith("SerialError"), result.stdout + result.stderr
    assert "in use" in result.stdout, result.stdout


def test_refused_second_open_leaves_the_first_lines_table_rate_alone(pty, open_line):
    first = open_line(pty, baudrate=19200, format=LineFormat.parse("8n2"))
    with pytest.raises(SerialError, match="in use"):
        open_line(pty, baudrate=9600)
    cflag, rate = first.port.settings()
    assert rate == 19200
    assert cflag & termios.CSTOPB


def test_line_can_be_opened_again_after_close(pty, open_line):
    open_line(pty, baudrate=19200).close()
    assert open_line(pty, baudrate=19200).port.settings()[1] == 19200


def test_missing_device_is_a_serial_error(tmp_path):
    with pytest.raises(SerialError, match="cannot open"):
        SerialLine(SerialConfig(str(tmp_path / "ttyNONE")))


# ---------------------------------------------------------------------------------------------
# Configuration
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("text, bits, parity, stop", [
    ("8m1", 8, "m", 1), ("8s1", 8, "s", 1), ("7m2", 7, "m", 2), ("7s1", 7, "s", 1),
    ("8M1", 8, "m", 1), ("7S2", 7, "s", 2),
])
def test_mark_and_space_formats_are_accepted(text, bits, parity, stop):
    assert LineFormat.parse(text) == LineFormat(bits, parity, stop)


@pytest.mark.parametrize("text", ["9n1", "8x1", "6n1", "8n3", "8n0", "8n", "n81", "", "8n1 ",
                                  "8nn1", "88n1"])
def test_bad_formats_are_refused(text):
    with pytest.raises(ConfigError):
        LineFormat.parse(text)


@pytest.mark.parametrize("fmt, bits", [("8n1", 10), ("8e1", 11), ("8m1", 11), ("8s2", 12),
                                       ("7n1", 9), ("7s1", 10)])
def test_character_time_counts_mark_and_space_parity_bits(fmt, bits):
    cfg = SerialConfig("/dev/null", baudrate=9600, format=LineFormat.parse(fmt))
    assert cfg.char_ns == bits * 1_000_000_000 // 9600
    assert cfg.t35_us == -(-35 * bits * 1_000_000 // (10 * 9600))   # 3.5 chars, rounded up


def test_silence_replaces_t35_as_end_of_frame():
    cfg = SerialConfig("/dev/null", baudrate=19200, silence_ms=20)
    assert cfg.end_of_frame_us == 20_000
    assert SerialConfig("/dev/null", baudrate=19200).end_of_frame_us == 1823  # 3.5*10/19200 s
    assert SerialConfig("/dev/null", baudrate=38400).end_of_frame_us == 1750


@pytest.mark.parametrize("text, kind, echo", [
    ("rs232", "rs232", False), ("rs422", "rs422", False), ("rs485", "rs485", False),
    ("rs485 noecho", "rs485", False), ("rs485 echo", "rs485", True), ("RS485 ECHO", "rs485", True),
])
def test_interfaces_accepted(text, kind, echo):
    assert Interface.parse(text) == Interface(kind, echo)


@pytest.mark.parametrize("text", ["", "rs484", "rs232 echo", "rs422 echo", "rs485 echo echo",
                                  "rs485 loud", "echo", "usb"])
def test_interfaces_refused(text):
    with pytest.raises(ConfigError):
        Interface.parse(text)


@pytest.mark.parametrize("baud", [50, 7200, 4000000])
def test_baud_rate_bounds_accepted(baud):
    assert SerialConfig("/dev/null", baudrate=baud).baudrate == baud


@pytest.mark.parametrize("baud", [0, 49, 4000001])
def test_baud_rate_bounds_refused(baud):
    with pytest.raises(ConfigError, match=str(baud)):
        SerialConfig("/dev/null", baudrate=baud)


def test_protocol_refused():
    with pytest.raises(ConfigError):
        SerialConfig("/dev/null", protocol="tcp")


# ---------------------------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------------------------

def _help_entries() -> dict[str, str]:
    """--option -> its help text in `mbgw slave --help`, whitespace folded."""
    result = CliRunner().invoke(main, ["slave", "--help"])
    assert result.exit_code == 0, result.output
    entries: dict[str, str] = {}
    current = None
    for line in result.output.split("Options:", 1)[1].splitlines():
        match = re.match(r"^  (--[a-z-]+)", line)
        if match:
            current = match[1]
            entries[current] = line
        elif current:
            entries[current] += " " + line
    return {k: " ".join(v.split()) for k, v in entries.items()}


@pytest.mark.parametrize("option, default, values", [
    ("--protocol", "rtu", ["rtu", "ascii"]),
    ("--baudrate", "9600", ["50", "4000000"]),
    ("--format", "8n1", ["7", "8", "n", "e", "o", "m", "s", "1", "2"]),
    ("--interface", "rs232", ["rs232", "rs422", "rs485 noecho", "rs485 echo"]),
    ("--rtsdelays", "0, 0", ["0..255"]),
    ("--silence", "0", ["0..65535"]),
    ("--ascii-timeout", "1000", ["1..65535"]),
    ("--stout", "600", ["1..65535"]),
])
def test_help_documents_default_and_range(option, default, values):
    text = _help_entries()[option]
    assert f"[default: {default}" in text, text
    for value in values:
        assert value in text, (value, text)


def test_help_documents_the_nocheck_default():
    text = _help_entries()["--nocheck"]
    assert "default" in text.lower(), text


def test_help_says_nocheck_is_for_debugging():
    assert "debug" in _help_entries()["--nocheck"].lower()


@pytest.mark.parametrize("args, option", [
    (["--protocol", "tcp"], "--protocol"),
    (["--format", "9n1"], "--format"),
    (["--format", "8x1"], "--format"),
    (["--interface", "rs485 loud"], "--interface"),
    (["--interface", "rs232 echo"], "--interface"),
    (["--rtsdelays", "256", "0"], "--rtsdelays"),
    (["--rtsdelays", "0", "-1"], "--rtsdelays"),
    (["--rtsdelays", "5"], "--rtsdelays"),
    (["--baudrate", "49"], "--baudrate"),
    (["--baudrate", "4000001"], "--baudrate"),
    (["--baudrate", "fast"], "--baudrate"),
    (["--silence", "-1"], "--silence"),
    (["--silence", "65536"], "--silence"),
    (["--ascii-timeout", "0"], "--ascii-timeout"),
    (["--ascii-timeout", "65536"], "--ascii-timeout"),
    (["--stout", "0"], "--stout"),
    (["--nocheck=yes"], "--nocheck"),
])
def test_bad_values_exit_2_naming_the_option(tmp_path, args, option):
    result = CliRunner().invoke(main, ["slave", "--device", str(tmp_path / "tty"), *args])
    assert result.exit_code == 2, result.output
    assert option in result.output, result.output
