"""The console shows northbound MQTT (issue 28, issue 30): the session and its counts on the
Overview, and on the Lines page each line's state as the broker got it, beside its state
here.  One daemon for the module: Debian's Mosquitto, pymodbus's RTU slave on line serial,
an idle second line, and a subscriber that saw the node's birth."""
import shutil

import pytest

from tests.harness import Gateway, Peer, PtyPair
from tests.integration.northbound.test_sparkplug import SLAVE, decode, metrics, scenarios
from tests.integration.scenarios.test_scenarios_serial import write_config
from tests.integration.web.chrome import DESKTOP, PHONE, assert_fits, browser, page_of_size
from tests.integration.web.test_web_ui import console_file, go, log_in, text_in, wait
from tests.ops import status
from tests.peers.broker import MOSQUITTO, Broker, Subscriber
from tests.wait import until

pytestmark = pytest.mark.integration

__all__ = ["browser"]                    # the console tests' Chromium, a fixture
NODE = "gw1"
NBIRTH = f"spBv1.0/mbgw/NBIRTH/{NODE}"


class Northbound:
    """`mbgw slave` publishing its scenarios to Mosquitto (Sparkplug, node gw1), line serial
    polled, line meters idle, the console on; the subscriber there before the gateway."""

    def __init__(self, directory) -> None:
        self.broker = Broker(directory)
        self.subscriber = Subscriber(self.broker.port, "spBv1.0/#")
        self.pairs = {}
        for name in ("serial", "meters"):
            (directory / name).mkdir()
            self.pairs[name] = PtyPair(directory / name)
        self.peer = Peer("pymodbus_slave.py", self.pairs["serial"].device, str(SLAVE))
        path = directory / "mbgw.toml"
        write_config(path, scenarios())
        self.url = console_file(path, [
            *path.read_text().splitlines(),
            "[mqtt]", f'broker = "{self.broker.url}"', f'node = "{NODE}"',
            "[[line]]", 'name = "meters"', f'device = "{self.pairs["meters"].gateway}"',
            "baudrate = 19200"])
        self.gw = Gateway(directory, self.pairs["serial"].gateway, "--config", str(path))

    def stop(self) -> None:
        self.gw.stop()
        self.peer.stop()
        for pair in self.pairs.values():
            pair.stop()
        self.subscriber.close()
        self.broker.stop()


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    if shutil.which(MOSQUITTO) is None:
        pytest.skip("mosquitto is not installed (scripts/setup.sh installs it)")
    running = Northbound(tmp_path_factory.mktemp("mqtt-console"))
    yield running
    running.stop()


def test_the_overview_has_an_mqtt_block(daemon, browser):
    log_in(browser, daemon, "admin")
    wait(browser, text_in('#overview-mqtt-facts tr[data-name="Connected"] td', "yes"))
    shown = browser.find_element("css selector", '#overview-mqtt-facts tr[data-name="Broker"] td')
    assert shown.text == f"{daemon.broker.url} (sparkplug, node {NODE})"
    assert status(daemon.gw)["mqtt"]["connected"] is True


def test_the_lines_page_has_the_session_and_each_line_as_the_broker_got_it(daemon, browser):
    birth = until(lambda: daemon.subscriber.received("/NBIRTH/"), "an NBIRTH", 10)
    sent = metrics(decode(birth[0][2]))
    assert birth[0][1] == NBIRTH
    assert (sent["Lines/serial/State"], sent["Lines/meters/State"]) == ("up", "up")
    log_in(browser, daemon, "admin")
    go(browser, "lines")
    wait(browser, text_in('#lines-mqtt-facts tr[data-name="Connected"] td', "yes"))
    sent_count = status(daemon.gw)["mqtt"]["messages_sent"]
    wait(browser, lambda d: int(d.find_element(
        "css selector", '#lines-mqtt-facts tr[data-name="Messages sent"] td').text)
        >= sent_count > 0)
    assert browser.find_element(
        "css selector", '#lines-mqtt-facts tr[data-name="Dropped (slow broker)"] td').text == "0"
    for line in ("serial", "meters"):
        row = f'#lines-mqtt-table tr[data-line="{line}"]'
        expected = [line, f"Lines/{line}/State", "up", "up"]
        # read by a wait: the page may rebuild the table between two reads of its cells
        wait(browser, lambda d, row=row, expected=expected: [
            td.text for td in d.find_elements("css selector", f"{row} td")] == expected)
    assert status(daemon.gw)["mqtt"]["lines"] == {"serial": "up", "meters": "up"}


@pytest.mark.parametrize("size", [DESKTOP, PHONE], ids=["desktop", "phone"])
def test_the_lines_page_with_mqtt_is_no_wider_than_the_window(daemon, browser, size):
    with page_of_size(browser, size):
        log_in(browser, daemon, "admin")
        go(browser, "lines")
        wait(browser, text_in('#lines-mqtt-table tr[data-line="meters"] td.published', "up"))
        browser.execute_script("document.getElementById('lines-mqtt').scrollIntoView()")
        assert_fits(browser, "lines-mqtt-%dx%d" % size)
