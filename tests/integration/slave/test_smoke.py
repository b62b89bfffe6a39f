import subprocess

import pytest

pytestmark = pytest.mark.integration


def test_mbpoll_reads_registers_through_the_gateway(pty_pair, start_peer, start_gateway):
    start_peer("pymodbus_slave.py", pty_pair.device)
    gw = start_gateway(pty_pair.gateway, "--baudrate", "19200")
    out = subprocess.run(["mbpoll", "-m", "tcp", "-a", "17", "-p", str(gw.port), "-0", "-t", "4",
                          "-r", "0", "-c", "3", "-1", "127.0.0.1"],
                         capture_output=True, text=True, timeout=10)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "[0]: \t100" in out.stdout and "[2]: \t102" in out.stdout
