"""Modbus ASCII: the LRC and the ':' HEX LRC CR LF framing, against published frames."""
import pytest

from mbgw.errors import ChecksumError, FrameError
from mbgw.line import native
from tests.unit.vectors import CHECK_VECTORS

WITH_LRC = [v for v in CHECK_VECTORS if v.lrc is not None]
IDS = [v.where for v in WITH_LRC]


def _published_ascii(vector) -> bytes:
    """The ASCII frame as the sources print it: ':' then the bytes and the LRC as upper-case
    hex pairs, then CR LF."""
    return b":" + (vector.frame + bytes((vector.lrc,))).hex().upper().encode() + b"\r\n"


def test_published_ascii_example_literally():
    # Simply Modbus ASCII example ":1103006B00037E" for 11 03 00 6B 00 03.
    assert native.ascii_encode(bytes.fromhex("1103006B0003")) == b":1103006B00037E\r\n"


@pytest.mark.parametrize("vector", WITH_LRC, ids=IDS)
def test_lrc_matches_published_value(vector):
    assert native.lrc(vector.frame) == vector.lrc, vector.source


@pytest.mark.parametrize("vector", WITH_LRC, ids=IDS)
def test_encode_gives_the_published_frame(vector):
    assert native.ascii_encode(vector.frame) == _published_ascii(vector), vector.source


@pytest.mark.parametrize("vector", WITH_LRC, ids=IDS)
def test_decode_gives_back_the_bytes(vector):
    assert native.ascii_decode(_published_ascii(vector)) == vector.frame


def test_decode_accepts_lower_case_hex():
    assert native.ascii_decode(b":1103006b00037e\r\n") == bytes.fromhex("1103006B0003")


def test_decode_rejects_a_wrong_lrc():
    with pytest.raises(ChecksumError):
        native.ascii_decode(b":1103006B00037F\r\n")


@pytest.mark.parametrize("frame", [
    b"1103006B00037E\r\n",      # no ':'
    b":1103006B00037E\n",       # no CR
    b":1103006B00037E",         # no CR LF
    b":1103006B00037\r\n",      # odd number of hex characters
    b":11G3006B00037E\r\n",     # not hex
])
def test_decode_rejects_malformed_frames(frame):
    with pytest.raises(FrameError):
        native.ascii_decode(frame)


def test_two_threads_encode_and_decode_their_own_frames():
    """Two ASCII lines each have a thread; the C calls release the GIL, so each must keep its
    own buffers.  Frames from the Modbus over serial line specification's LRC example shape:
    01 03 0000 0001 (LRC FB) and 11 03 0001 0002 (LRC E9)."""
    import threading

    from mbgw.line import native

    cases = [(bytes.fromhex("010300000001"), b":010300000001FB\r\n"),
             (bytes.fromhex("110300010002"), b":110300010002E9\r\n")]
    wrong = []

    def run(adu: bytes, frame: bytes) -> None:
        for _ in range(20000):
            if native.ascii_encode(adu) != frame or native.ascii_decode(frame) != adu:
                wrong.append(adu)
                return

    threads = [threading.Thread(target=run, args=case) for case in cases]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert wrong == []
