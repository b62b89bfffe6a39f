"""Every page of the console at a desktop's 1280×800 and a phone's 390×844: no page wider
than the window (a wide table scrolls in its own box), every action within reach, and a
screenshot of each kept in artifacts/console/ (docs/console-*.png are copies of some)."""
import pytest

from tests.integration.web.chrome import DESKTOP, PHONE, assert_fits, start_chromium
from tests.integration.web.test_web_ui import (
    PAGE_LOADED,
    TABLE_UNIT,
    Console,
    found,
    go,
    log_in,
    wait,
)
from tests.modbus import Client, read_holding

pytestmark = pytest.mark.integration

PAGES = {"overview": "#overview-facts", **PAGE_LOADED, "firewall": "#firewall-rules",
         "events": "#events-table",
         "admin": "#system-table"}


@pytest.fixture(scope="module")
def console(tmp_path_factory):
    running = Console(tmp_path_factory.mktemp("pages"))
    yield running
    running.stop()


@pytest.fixture(scope="module", params=[DESKTOP, PHONE], ids=["desktop", "phone"])
def sized(request):
    driver = start_chromium(*request.param)
    yield driver, "%dx%d" % request.param
    driver.quit()


def test_no_page_is_wider_than_the_window_and_every_action_is_in_reach(sized, console):
    browser, size = sized
    modbus = Client(console.gw.port)            # a row on Clients, with its Close
    try:
        modbus.ask(TABLE_UNIT, read_holding(0, 1))
        log_in(browser, console, "admin")
        for page, loaded in PAGES.items():
            go(browser, page)
            wait(browser, found(loaded))
            if page == "clients":
                wait(browser, found("#clients-table button.close-client"))
            assert_fits(browser, f"{page}-{size}")
    finally:
        modbus.close()
