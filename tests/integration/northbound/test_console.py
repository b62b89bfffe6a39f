"""The console's overview shows northbound MQTT: the session and its counts, as the status
has them (issue 28)."""
from types import SimpleNamespace

import pytest

from tests.harness import free_port
from tests.integration.northbound.test_sparkplug import SLAVE, scenarios
from tests.integration.scenarios.test_scenarios_serial import write_config
from tests.integration.web.test_web_ui import browser, log_in, set_password, text_in, wait
from tests.ops import status

pytestmark = pytest.mark.integration

__all__ = ["browser"]                    # the web tests' Chromium, a fixture


def test_the_overview_has_an_mqtt_block(tmp_path, pty_pair, start_peer, start_gateway,
                                        broker, browser):
    start_peer("pymodbus_slave.py", pty_pair.device, str(SLAVE))
    path = tmp_path / "mbgw.toml"
    web_port = free_port()
    write_config(path, scenarios())
    path.write_text(path.read_text() + f'[web]\nlisten = "127.0.0.1:{web_port}"\n'
                    f'[mqtt]\nbroker = "{broker.url}"\nnode = "gw1"\n')
    set_password(path, "admin")
    gw = start_gateway(pty_pair.gateway, "--config", str(path))
    log_in(browser, SimpleNamespace(url=f"http://127.0.0.1:{web_port}/"), "admin")
    wait(browser, text_in('#overview-mqtt-facts tr[data-name="Connected"] td', "yes"))
    shown = browser.find_element("css selector", '#overview-mqtt-facts tr[data-name="Broker"] td')
    assert shown.text == f"{broker.url} (sparkplug, node gw1)"
    assert status(gw)["mqtt"]["connected"] is True
