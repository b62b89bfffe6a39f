"""What the table tests share: a gateway to reload."""
import pytest

from tests.integration.ops.test_reload import config_set


@pytest.fixture
def reloadable(tmp_path, pty_pair, start_peer, start_gateway, client):
    """reloadable(unit) -> (its file, the gateway, a client): pymodbus's slave answering unit
    on the line, the gateway started from a file `mbgw config set` wrote (19200 baud, stout
    100 ms, exceptions on) for the test to change and reload."""
    def start(unit: int):
        start_peer("pymodbus_slave.py", pty_pair.device, str(unit), "--silent-unknown")
        path = tmp_path / "mbgw.toml"
        for words in (("serial", "baudrate", "19200"), ("serial", "stout", "100"),
                      ("net", "exception", "on")):
            config_set(path, *words)
        gw = start_gateway(pty_pair.gateway, "--config", str(path))
        return path, gw, client(gw)
    return start
