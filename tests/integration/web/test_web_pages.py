"""Every page of the console at a desktop's 1280×800 and a phone's 390×844: no page wider
than the window (a wide table scrolls in its own box), every action within reach, and a
screenshot of each kept in artifacts/console/ (docs/console-*.png are copies of some)."""
from pathlib import Path

import pytest

from tests.integration.web.chrome import DESKTOP, PHONE, start_chromium
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

ARTIFACTS = Path(__file__).resolve().parents[3] / "artifacts" / "console"
PAGES = {"overview": "#overview-facts", **PAGE_LOADED, "firewall": "#firewall-rules",
         "events": "#events-table",
         "admin": "#system-table"}

# The widest the page is, and the buttons out of reach: right of the window, or hidden
# sideways in a box (a row's actions stick to the box's right edge, so they are in view).
MEASURE = """
const out = [];
for (const b of document.querySelectorAll("#page button, header button")) {
  const r = b.getBoundingClientRect();
  if (r.width && (r.right > window.innerWidth + 1 || r.left < -1)) out.push(b.textContent);
}
return [document.documentElement.scrollWidth, window.innerWidth, out];
"""


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
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    modbus = Client(console.gw.port)            # a row on Clients, with its Close
    try:
        modbus.ask(TABLE_UNIT, read_holding(0, 1))
        log_in(browser, console, "admin")
        for page, loaded in PAGES.items():
            go(browser, page)
            wait(browser, found(loaded))
            if page == "clients":
                wait(browser, found("#clients-table button.close-client"))
            width, window, unreachable = browser.execute_script(MEASURE)
            browser.save_screenshot(str(ARTIFACTS / f"{page}-{size}.png"))
            assert width <= window, f"{page} at {size}: {width} px wide in {window}"
            assert unreachable == [], f"{page} at {size}: {unreachable} out of reach"
    finally:
        modbus.close()
