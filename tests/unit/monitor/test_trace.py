"""A monitor line's frames as `mbgw trace` prints them: the line, the serial address, the
function and the outcome (a CRC error, an unanswered request)."""
from mbgw.cli.render_trace import format_event
from mbgw.monitor.line_thread import _event
from mbgw.ops.trace import is_error


def shown(adu: bytes, what: str) -> str:
    event = _event(adu, what)
    event["line"] = "tap"          # as the line's LineTrace names it
    return format_event(event)


def test_a_reply_heard_shows_its_line_address_and_function() -> None:
    row = shown(bytes.fromhex("070304000b0016"), "reply")
    assert row.split()[1:] == ["reply", "monitor", "(heard)", "-", "7", "0x03", "6", "reply"]


def test_an_unanswered_request_and_a_crc_error_show_their_outcome() -> None:
    assert shown(bytes.fromhex("0904000000020000"), "unanswered").endswith("timeout")
    assert shown(b"\x07", "crc error").split()[1:] == ["ignored", "monitor", "(heard)", "-",
                                                        "7", "0x00", "0", "crc", "error"]


def test_a_crc_error_passes_the_errors_filter_and_a_request_does_not() -> None:
    assert is_error(_event(b"\x07", "crc error"))
    assert not is_error(_event(bytes.fromhex("0904000000020000"), "request"))
