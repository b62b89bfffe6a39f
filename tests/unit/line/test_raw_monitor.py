"""The raw line monitor's bursts (mbgw.line.raw): what the C capture recorded, cut at the
silences and marked.  The frames are the spec's published vector (Modbus over Serial Line
V1.02, 11 03 006B 0003 with CRC 76 87) and a reply built on it."""
from mbgw.line.raw import RawMonitor
from tests.modbus import crc16

CHAR_NS = 100_000                 # a character time
QUIET_US = 350                    # t3.5
REQUEST = bytes.fromhex("11 03 006B 0003 7687")
REPLY_PDU = bytes.fromhex("11 03 06 022B 0000 0064")


REPLY = REPLY_PDU + crc16(REPLY_PDU)
MS = 1_000_000


def monitor() -> RawMonitor:
    return RawMonitor(CHAR_NS, QUIET_US, stout_ms=100)


def shown(events):
    return [(e["kind"], bytes.fromhex(e["bytes"]), e["gap_us"]) for e in events]


def test_a_reply_read_in_pieces_is_one_burst_and_the_gaps_are_silences():
    sent_at = 10 * MS                 # the request leaves in 8 character times: until 10.8 ms
    got = shown(monitor().events([
        (True, sent_at, REQUEST),
        (False, 13 * MS, REPLY[:5]),          # began 0.5 ms before: a 1.7 ms silence
        (False, 13 * MS + 600_000, REPLY[5:]),
        (True, 20 * MS, REQUEST)]))
    assert got == [("request", REQUEST, None), ("reply", REPLY, 1700),
                   ("request", REQUEST, 20 * 1000 - 13_600)]


def test_bytes_that_make_no_valid_reply_are_noise_and_after_stout_unsolicited():
    bad = REPLY[:-1] + bytes((REPLY[-1] ^ 1,))
    other = bytes.fromhex("12 03 02 0001") + crc16(bytes.fromhex("12 03 02 0001"))
    got = shown(monitor().events([
        (True, 0, REQUEST),
        (False, 5 * MS, bad),                    # a bad CRC
        (False, 20 * MS, other),                 # another address
        (False, 300 * MS, REPLY)]))              # after stout: nobody asked
    assert [kind for kind, _, _ in got] == ["request", "noise", "noise", "unsolicited"]


def test_a_silence_of_t35_ends_a_burst():
    got = shown(monitor().events([
        (False, 1 * MS, b"\x55\xaa"),
        (False, 1 * MS + 300_000, b"\x55"),          # 0.2 ms after: the same burst
        (False, 3 * MS, b"\x01")]))                   # 1.6 ms after: another one
    assert got == [("unsolicited", b"\x55\xaa\x55", None), ("unsolicited", b"\x01", 1600)]
