"""A monitor line's port settings: RTS held low unless the kernel's RS-485 mode switches it,
DTR low."""
from mbgw.config.lines import LineConfig
from mbgw.config.model import Interface, SerialConfig
from mbgw.monitor.line_thread import listening


def test_an_rs232_line_holds_rts_low_whatever_the_file_says() -> None:
    for rts, cts in (("high", "ignore"), ("flow", "flow"), ("modem", "ignore")):
        line = LineConfig("tap", SerialConfig("/dev/null", rts=rts, cts=cts), mode="monitor")
        assert (listening(line).serial.rts, listening(line).serial.cts) == ("low", "ignore")


def test_an_rs485_line_leaves_rts_to_the_kernels_mode() -> None:
    line = LineConfig("tap", SerialConfig("/dev/null", interface=Interface("rs485")),
                      mode="monitor")
    serial = listening(line).serial
    assert (serial.rts, serial.cts, serial.interface) == (line.serial.rts, line.serial.cts,
                                                          line.serial.interface)
    assert listening(line) == LineConfig(
        "tap", SerialConfig("/dev/null", interface=Interface("rs485"), dtr="low"),
        mode="monitor")


def test_dtr_is_held_low_whatever_the_file_says() -> None:
    for interface in (Interface("rs232"), Interface("rs485")):
        line = LineConfig("tap", SerialConfig("/dev/null", dtr="high", interface=interface),
                          mode="monitor")
        assert listening(line).serial.dtr == "low"
