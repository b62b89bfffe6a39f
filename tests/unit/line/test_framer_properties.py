"""Properties of the Python framers, on inputs hypothesis makes: the MBAP splitter
(mbgw/line/native.py), the PDU helpers (pdu.py), RTU and ASCII on the line
(mbgw/slave/framing.py's framings over the C core's rules in mbgw/line/native.py), and
transparent mode's frames (mbgw/transparent/frames.py).  Round trips give back what went
in; random bytes never raise anything but the documented errors (BadHeader; ChecksumError
and FrameError)."""
import struct

from hypothesis import given, settings
from hypothesis import strategies as st

from mbgw.config.model import SerialConfig
from mbgw.config.transparent import EOF_KINDS, TransparentConfig
from mbgw.errors import BadHeader, ChecksumError, FrameError
from mbgw.line import native
from mbgw.line.native import Reception
from mbgw.protocol import pdu
from mbgw.slave.framing import AsciiFraming
from mbgw.transparent.frames import MAX_FRAME, Receiver, Rules, from_registers, to_registers

PDUS = st.binary(min_size=1, max_size=253)
ADUS = st.builds(lambda address, body: bytes([address]) + body,
                 st.integers(0, 255), PDUS)
settings.register_profile("mbgw", deadline=None)     # a loaded machine is no failure
settings.load_profile("mbgw")


# --- MBAP ------------------------------------------------------------------------------------

@given(st.lists(st.tuples(st.integers(0, 0xFFFF), st.integers(0, 255), PDUS), max_size=8),
       st.lists(st.integers(1, 64), max_size=20))
def test_mbap_frames_come_back_whole_however_the_stream_is_cut(sent, cuts):
    stream = b"".join(native.frame(tid, unit, body) for tid, unit, body in sent)
    buf, got, at = bytearray(), [], 0
    for cut in [*cuts, len(stream)]:
        buf += stream[at:at + cut]
        at += cut
        got += list(native.split_frames(buf))
    assert got == sent and not buf


@given(st.binary(max_size=600))
def test_mbap_random_bytes_give_frames_or_bad_header_nothing_else(data):
    buf = bytearray(data)
    try:
        for tid, unit, body in native.split_frames(buf):
            assert 0 <= tid <= 0xFFFF and 0 <= unit <= 255 and 1 <= len(body) <= 253
    except BadHeader:
        return
    assert len(buf) < native.HEADER_LEN or \
        len(buf) < 6 + struct.unpack_from(">H", buf, 4)[0]      # what is left is a start


@given(st.integers(0, 255), st.integers(0, 255))
def test_an_exception_pdu_is_the_function_flagged_and_its_code(function, code):
    assert pdu.exception_pdu(function, code) == bytes((function | 0x80, code))


# --- RTU and ASCII on the line ---------------------------------------------------------------

@given(ADUS)
def test_rtu_a_frame_with_its_crc_checks_and_a_changed_byte_does_not(adu):
    crc = native.crc16(adu)
    frame = adu + struct.pack("<H", crc)
    assert native.crc16(frame) == 0
    spoiled = bytes([frame[0] ^ 0x01]) + frame[1:]
    assert native.crc16(spoiled) != 0


@given(st.binary(min_size=1, max_size=native.RTU_MAX_ADU - 2))
def test_rtu_a_request_length_once_known_stays_as_bytes_come(data):
    known = 0
    for have in range(len(data) + 1):
        n = native.rtu_request_length(data[:have])
        assert n == 0 or n == native.LEN_UNKNOWN or n >= 4
        if known:
            assert n == known
        known = n


@given(st.binary(min_size=2, max_size=252))
def test_ascii_round_trip(adu):
    line = native.ascii_encode(adu)
    assert line[:1] == b":" and line[-2:] == b"\r\n" and line[1:-2] == line[1:-2].upper()
    assert native.ascii_decode(line) == adu
    assert native.ascii_decode(line.lower()) == adu            # lower case hex is taken


@given(st.binary(max_size=native.ASCII_MAX_FRAME + 8))
def test_ascii_random_bytes_decode_or_raise_the_documented_errors(data):
    try:
        adu = native.ascii_decode(data)
    except (ChecksumError, FrameError):
        return
    assert native.ascii_encode(adu).upper() == data.upper()


class _Line:
    """What AsciiFraming reads: a port whose read_ascii hands over one frame (the bytes
    hypothesis made) and the counters it books into."""

    class cfg:
        ascii_timeout_ms = 1000

    class counters:
        noise_bytes = 0
        bytes_received = 0

    def __init__(self, frame: bytes) -> None:
        self.port = self
        self._frame = frame

    def read_ascii(self, deadline, interchar_us) -> Reception:
        return Reception(self._frame, None, -1, len(self._frame), 0, -1, 0, 0)


@given(st.binary(max_size=600), st.integers(0, 255))
def test_ascii_framing_on_random_frames_returns_a_checked_frame_or_a_fault(data, address):
    got = AsciiFraming(_Line(data)).receive(bytes([address, 3]), deadline=0)
    if got.frame is not None:
        assert got.frame[0] == address and len(got.frame) >= 2
        assert native.ascii_decode(data) == got.frame
    else:
        assert isinstance(got.fault, (ChecksumError, FrameError)) or \
            got.foreign_address not in (-1, address)


@given(ADUS.filter(lambda a: len(a) >= 2), st.integers(0, 255))
def test_ascii_framing_takes_its_own_address_and_refuses_another(adu, address):
    got = AsciiFraming(_Line(native.ascii_encode(adu))).receive(bytes([address, 3]), 0)
    if adu[0] == address:
        assert got.frame == adu
    else:
        assert got.frame is None and got.foreign_address == adu[0]


# --- transparent mode ------------------------------------------------------------------------

RULES = st.builds(lambda eof, crc, trigger, size: TransparentConfig(
    eof=eof, crc=crc, trigger=trigger, rx_size=size, tx_size=size),
    st.sampled_from(EOF_KINDS), st.booleans(), st.booleans(), st.integers(1, 250))


@given(st.binary(max_size=500))
def test_transparent_registers_round_trip(data):
    assert from_registers(to_registers(data), len(data)) == data


@given(RULES, st.binary(max_size=2 * MAX_FRAME), st.lists(st.integers(1, 300), max_size=30))
def test_transparent_receiver_cuts_frames_out_of_any_bytes_however_they_come(cfg, data, cuts):
    rules = Rules(cfg, SerialConfig("/dev/x"))
    receiver = Receiver(rules)
    taken, at, dropped = [], 0, False
    for cut in [*cuts, len(data)]:
        got, overflow = receiver.feed(data[at:at + cut])
        at += cut
        taken += got
        dropped |= overflow
        assert len(receiver.pending) <= MAX_FRAME
    for frame in taken:
        assert rules.complete_length(bytearray(frame)) == len(frame)
        payload = rules.payload(frame)
        assert payload is None or frame.startswith(payload)
    if not dropped:
        assert b"".join(taken) + bytes(receiver.pending) == data


@given(RULES, st.binary(min_size=1, max_size=250))
def test_transparent_a_frame_sent_from_the_tx_area_is_received_as_it_went(cfg, data):
    rules = Rules(cfg, SerialConfig("/dev/x"))
    area = (b"\x01" if cfg.trigger else b"") + data
    frame, _ = rules.tx_frame(area, None if not cfg.trigger else 0)
    if not frame or cfg.eof == "timeout":
        return                                  # nothing to send, or it ends by silence
    got, _ = Receiver(rules).feed(frame)
    assert got == [frame]
    payload = rules.payload(frame)
    assert payload is not None and frame.startswith(payload)
