"""Which paths can never be the serial device (mbgw.config.device): refused at start, reload
and check-config (exit 78), while a device that is not there yet is waited for."""
import os
import socket

import pytest

from mbgw.config.device import device_problem


def test_a_character_device_is_one():
    assert device_problem("/dev/null") is None     # a character device; opening tells more


@pytest.mark.parametrize("path", ["/dev/ttyUSB97", "/dev/serial/by-id/usb-FTDI_none-if00-port0",
                                  "/dev/no/such/directory/yet/ttyX"])
def test_a_device_not_there_yet_is_fine(path):
    assert device_problem(path) is None


def test_a_link_to_nothing_is_a_device_not_there_yet(tmp_path):
    link = tmp_path / "ttyGW"
    link.symlink_to(tmp_path / "gone")
    assert device_problem(str(link)) is None


def test_a_link_to_a_character_device_is_one(tmp_path):
    link = tmp_path / "ttyGW"
    link.symlink_to("/dev/null")
    assert device_problem(str(link)) is None


def test_what_can_never_be_a_serial_device(tmp_path):
    regular = tmp_path / "file"
    regular.write_text("")
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    sock_path = tmp_path / "sock"
    with socket.socket(socket.AF_UNIX) as sock:
        sock.bind(str(sock_path))
        assert device_problem(str(sock_path)) == f"device {sock_path}: a socket, not a serial " \
                                                 f"device"
    assert device_problem(str(regular)) == f"device {regular}: a regular file, not a serial " \
                                           f"device"
    assert device_problem(str(tmp_path)) == f"device {tmp_path}: a directory, not a serial " \
                                            f"device"
    assert device_problem(str(fifo)) == f"device {fifo}: a FIFO, not a serial device"
    under_file = regular / "deeper" / "ttyUSB0"
    assert device_problem(str(under_file)) == (
        f"device {under_file}: {regular} is not a directory, so nothing can appear there")
    assert device_problem("ttyUSB0") == "device 'ttyUSB0': not an absolute path (e.g. " \
                                        "/dev/ttyUSB0)"
    assert device_problem("") == "device: empty; expected a path such as /dev/ttyUSB0"
