"""Validated settings (mbgw.config.model): line format, character time, t3.5, baud rate, authip."""
import ipaddress

import pytest

from mbgw.config.model import Demotion, Interface, LineFormat, SerialConfig, SlaveConfig, parse_ip
from mbgw.errors import ConfigError

# The rates libmodbus 3.1.6 sets itself (/work/shared/notes/libmodbus.md 2.7).
LIBMODBUS_RATES = (110, 300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400,
                   460800, 500000, 576000, 921600, 1000000, 1152000, 1500000, 2500000, 3000000,
                   3500000, 4000000)


def _serial(baudrate: int = 9600, fmt: str = "8n1") -> SerialConfig:
    return SerialConfig("/dev/ttyS0", baudrate=baudrate, format=LineFormat.parse(fmt))


# --- LineFormat ---

@pytest.mark.parametrize("text, expected", [
    ("8n1", LineFormat(8, "n", 1)),
    ("8e1", LineFormat(8, "e", 1)),
    ("8o1", LineFormat(8, "o", 1)),
    ("8n2", LineFormat(8, "n", 2)),
    ("7e1", LineFormat(7, "e", 1)),
    ("7o2", LineFormat(7, "o", 2)),
    ("8E1", LineFormat(8, "e", 1)),
    ("7N2", LineFormat(7, "n", 2)),
    ("8m1", LineFormat(8, "m", 1)),
    ("8S1", LineFormat(8, "s", 1)),
])
def test_format_parse(text, expected):
    assert LineFormat.parse(text) == expected


@pytest.mark.parametrize("text", ["8n1", "7e1", "8o2"])
def test_format_prints_as_it_parses(text):
    assert str(LineFormat.parse(text)) == text


def test_default_format_is_8n1():
    assert LineFormat() == LineFormat.parse("8n1")


@pytest.mark.parametrize("text", ["9x1", "9n1", "6n1", "8x1", "8n3", "8n0", "8n", "n1", "",
                                  "8n11", "x8n1", "8 n 1", "8-n-1"])
def test_format_parse_rejects(text):
    with pytest.raises(ConfigError, match="format"):
        LineFormat.parse(text)


def test_format_error_names_the_value():
    with pytest.raises(ConfigError, match="9x1"):
        LineFormat.parse("9x1")


def test_format_parse_rejects_a_trailing_newline():
    with pytest.raises(ConfigError):
        LineFormat.parse("8n1\n")


@pytest.mark.parametrize("text, bits", [
    ("8n1", 10), ("8e1", 11), ("8o1", 11), ("8n2", 11), ("8e2", 12),
    ("7n1", 9), ("7e1", 10), ("7o2", 11), ("7n2", 10),
    ("8m1", 11), ("8s1", 11), ("7m2", 11),     # mark and space are parity bits too
])
def test_char_bits_counts_start_data_parity_and_stop_bits(text, bits):
    assert LineFormat.parse(text).char_bits == bits


# --- character time and t3.5 (Serial Line V1.02, 2.5.1.1) ---

def test_char_time_at_9600_8n1():
    assert _serial(9600, "8n1").char_ns == 1_041_666          # 10 bits / 9600 bit/s


@pytest.mark.parametrize("baudrate, fmt, t35_us", [
    (9600, "8n1", 3646),      # 3.5 * 10 / 9600 s = 3645.8 us, rounded up
    (9600, "8e1", 4011),      # the spec's 11-bit example: 4010.4 us
    (19200, "8n1", 1823),     # 1822.9 us: 19200 still uses 3.5 characters
    (19200, "8e1", 2006),     # 2005.2 us
    (1200, "8n1", 29167),     # 29166.7 us
    (4800, "7e1", 7292),      # 7291.7 us
])
def test_t35_is_three_and_a_half_characters_rounded_up_up_to_19200(baudrate, fmt, t35_us):
    assert _serial(baudrate, fmt).t35_us == t35_us


def test_t35_matches_the_spec_example_at_9600_with_11_bit_characters():
    # Serial Line V1.02 2.5.1.1: at 9600 with 11-bit characters, t3.5 = 4.01 ms.
    assert round(_serial(9600, "8e1").t35_us / 1000, 2) == 4.01


@pytest.mark.parametrize("baudrate", [38400, 57600, 115200, 230400, 1000000, 4000000])
@pytest.mark.parametrize("fmt", ["8n1", "8e2", "7e1"])
def test_t35_is_fixed_1750_us_above_19200(baudrate, fmt):
    # "For baud rates greater than 19200 Bps ... 1.750ms for inter-frame delay (t3.5)".
    assert _serial(baudrate, fmt).t35_us == 1750


# --- baud rate ---

@pytest.mark.parametrize("baudrate", LIBMODBUS_RATES)
def test_every_rate_libmodbus_sets_is_accepted(baudrate):
    assert _serial(baudrate).baudrate == baudrate


@pytest.mark.parametrize("baudrate", [50, 75, 14400, 12345, 2000000])
def test_rate_libmodbus_cannot_set_is_accepted_and_flagged(baudrate):
    # libmodbus 3.1.6 would silently run these at 9600 (notes/libmodbus.md 2.7); mbgw sets
    # them itself, so the config must say which ones libmodbus cannot.
    cfg = _serial(baudrate)
    assert cfg.baudrate == baudrate
    assert not cfg.libmodbus_baudrate


@pytest.mark.parametrize("baudrate", [9600, 19200, 230400, 4000000])
def test_rate_libmodbus_sets_is_flagged(baudrate):
    assert _serial(baudrate).libmodbus_baudrate


@pytest.mark.parametrize("baudrate", [0, -9600, 49, 4000001, 10_000_000])
def test_impossible_baudrate_is_rejected_naming_the_value(baudrate):
    with pytest.raises(ConfigError, match=rf"baudrate {baudrate}\b"):
        _serial(baudrate)


def test_default_serial_settings():
    cfg = SerialConfig("/dev/ttyS0")
    assert (cfg.baudrate, cfg.format, cfg.stout_ms) == (9600, LineFormat(8, "n", 1), 600)


# --- protocol, end of frame, interface ---

def test_protocol_is_rtu_or_ascii():
    assert SerialConfig("/dev/ttyS0").protocol == "rtu"
    assert SerialConfig("/dev/ttyS0", protocol="ascii").protocol == "ascii"
    with pytest.raises(ConfigError, match="tcp"):
        SerialConfig("/dev/ttyS0", protocol="tcp")


def test_end_of_frame_is_t35_unless_a_silence_is_set():
    assert SerialConfig("/dev/ttyS0", baudrate=9600).end_of_frame_us == 3646
    assert SerialConfig("/dev/ttyS0", baudrate=115200).end_of_frame_us == 1750
    assert SerialConfig("/dev/ttyS0", baudrate=9600, silence_ms=20).end_of_frame_us == 20000


def test_default_ascii_inter_character_timeout_is_one_second():
    # Serial Line V1.02 2.5.2.1: "up to 1 s" between characters by default.
    assert SerialConfig("/dev/ttyS0").ascii_timeout_ms == 1000


@pytest.mark.parametrize("text, kind, echo", [
    ("rs232", "rs232", False),
    ("rs422", "rs422", False),
    ("rs485", "rs485", False),
    ("rs485 noecho", "rs485", False),
    ("rs485 echo", "rs485", True),
    ("RS485 ECHO", "rs485", True),
    ("  rs485   echo ", "rs485", True),
])
def test_interface_parse(text, kind, echo):
    assert Interface.parse(text) == Interface(kind, echo)


@pytest.mark.parametrize("text", ["", "rs999", "rs232 echo", "rs422 noecho", "rs485 maybe",
                                  "rs485 echo echo", "echo"])
def test_interface_parse_rejects_naming_the_value(text):
    with pytest.raises(ConfigError, match="interface"):
        Interface.parse(text)


@pytest.mark.parametrize("text, expected", [
    # the guide: "Keywords rs422 and 4wires are synonyms", "rs485 and 2wires are synonyms"
    ("2wires", Interface("rs485")),
    ("2wires echo", Interface("rs485", echo=True)),
    ("2WIRES noecho", Interface("rs485")),
    ("4wires", Interface("rs422")),
    ("4wires master", Interface("rs422")),
    ("rs422 master", Interface("rs422")),
    ("rs422 slave", Interface("rs422", slave=True)),
    ("4wires slave", Interface("rs422", slave=True)),
])
def test_interface_takes_the_guides_words(text, expected):
    assert Interface.parse(text) == expected


@pytest.mark.parametrize("interface, shown, drives_rts", [
    (Interface("rs232"), "rs232", False), (Interface("rs422"), "rs422", False),
    (Interface("rs422", slave=True), "rs422 slave", True),
    (Interface("rs485"), "rs485", True), (Interface("rs485", echo=True), "rs485 echo", True),
])
def test_interface_prints_what_it_reads_back(interface, shown, drives_rts):
    assert str(interface) == shown and Interface.parse(shown) == interface
    assert interface.drives_rts is drives_rts


@pytest.mark.parametrize("text", ["2wires master", "4wires echo", "rs485 slave", "rs232 master",
                                  "3wires"])
def test_interface_refuses_an_option_of_the_other_kind(text):
    with pytest.raises(ConfigError, match="interface .*4wires.*2wires"):
        Interface.parse(text)


# --- RS-232 control lines ---

def test_control_lines_default_to_the_guides_defaults():
    cfg = SerialConfig("/dev/ttyS0")
    assert (cfg.dtr, cfg.rts, cfg.cts, cfg.xonxoff) == ("high", "high", "ignore", "ignore")
    assert cfg.wiring == "rs232" and not cfg.rts_ptt


@pytest.mark.parametrize("settings, message", [
    ({"rts": "flow"}, "rts flow with cts ignore: RTS/CTS flow control is both or neither"),
    ({"cts": "flow"}, "rts high with cts flow"),
    ({"rts": "modem", "interface": Interface("rs485")}, "rts modem: interface rs485 drives"),
    ({"rts": "low", "interface": Interface("rs422", slave=True)}, "rts low: interface rs422 sl"),
    ({"dtr": "modem"}, "dtr 'modem': expected high or low"),
    ({"xonxoff": "on"}, "xonxoff 'on': expected ignore or use"),
])
def test_control_lines_refused_naming_the_setting(settings, message):
    with pytest.raises(ConfigError, match=message):
        SerialConfig("/dev/ttyS0", **settings)


def test_control_lines_accepted_and_shown():
    cfg = SerialConfig("/dev/ttyS0", dtr="low", rts="flow", cts="flow", xonxoff="use")
    assert cfg.wiring == "rs232, dtr low, rts flow, cts flow, xonxoff use"
    assert SerialConfig("/dev/ttyS0", rts="modem").rts_ptt
    assert SerialConfig("/dev/ttyS0", interface=Interface("rs422"), rts="low").rts == "low"



@pytest.mark.parametrize("text", ["rs232", "rs422", "rs485", "rs485 echo"])
def test_interface_prints_as_it_parses(text):
    assert str(Interface.parse(text)) == text


def test_default_interface_is_rs232():
    assert SerialConfig("/dev/ttyS0").interface == Interface("rs232", False)


# --- authip ---

def test_eight_authip_entries_are_accepted():
    addresses = tuple(f"192.0.2.{i}" for i in range(1, 9))
    cfg = SlaveConfig(_serial(), authip=addresses)
    assert cfg.authip == tuple(ipaddress.ip_address(a) for a in addresses)


def test_nine_authip_entries_are_rejected():
    addresses = tuple(f"192.0.2.{i}" for i in range(1, 10))
    with pytest.raises(ConfigError, match=r"authip.*8.*9"):
        SlaveConfig(_serial(), authip=addresses)


def test_authip_entry_that_is_not_an_address_is_rejected_naming_it():
    with pytest.raises(ConfigError, match=r"authip 'notanip'"):
        SlaveConfig(_serial(), authip=("192.0.2.1", "notanip"))


@pytest.mark.parametrize("text", ["192.0.2.0/24", "host.example", "256.1.1.1", "", "::g"])
def test_parse_ip_rejects_non_addresses(text):
    with pytest.raises(ConfigError, match="authip"):
        parse_ip("authip", text)


def test_parse_ip_turns_ipv4_mapped_into_ipv4():
    assert parse_ip("authip", "::ffff:192.0.2.7") == ipaddress.IPv4Address("192.0.2.7")


def test_parse_ip_keeps_ipv6():
    assert parse_ip("authip", "2001:db8::1") == ipaddress.IPv6Address("2001:db8::1")


def test_slave_defaults_follow_the_acksys_commands():
    cfg = SlaveConfig(_serial())
    assert (cfg.slaveid, cfg.exception, cfg.authip, cfg.mdbport) == (0, False, (), 502)


@pytest.mark.parametrize("down_after, probe_interval_ms, named", [
    (-1, 5000, "down-after -1: out of range 0..100"),
    (101, 5000, "down-after 101: out of range 0..100"),
    (3, 99, "probe-interval 99: out of range 100..65535"),
    (3, 65536, "probe-interval 65536: out of range 100..65535"),
])
def test_demotion_settings_out_of_range_name_the_key(down_after, probe_interval_ms, named):
    with pytest.raises(ConfigError, match=named):
        Demotion(down_after, probe_interval_ms)


def test_the_late_window_is_stout_unless_set():
    serial = SerialConfig("/dev/ttyUSB0", stout_ms=300)
    assert SlaveConfig(serial=serial).late_window == 300
    assert SlaveConfig(serial=serial, late_window_ms=0).late_window == 0
    assert SlaveConfig(serial=serial, late_window_ms=1000).late_window == 1000
    with pytest.raises(ConfigError, match="late-window 65536: out of range 0..65535"):
        SlaveConfig(serial=serial, late_window_ms=65536)
