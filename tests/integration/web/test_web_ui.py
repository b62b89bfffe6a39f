"""The web console's pages in a real browser: Debian's chromium, headless, driven through
chromium-driver by selenium.  One browser for the module; waits are WebDriverWait conditions.

The escaping test serves the pages with a scripted API (a small aiohttp server of canned
documents whose strings carry markup: a gateway cannot be made to send those); the others run
against a real `mbgw slave` with its console on."""
import asyncio
import json
import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path
from types import SimpleNamespace

import pytest
from aiohttp import web
from pymodbus.client import ModbusTcpClient
from selenium.common.exceptions import StaleElementReferenceException
from selenium.webdriver.common.by import By
from selenium.webdriver.common.keys import Keys
from selenium.webdriver.support import expected_conditions as EC
from selenium.webdriver.support.ui import Select, WebDriverWait

from tests.harness import Gateway, Peer, PtyPair, free_port
from tests.integration.web.chrome import start_chromium
from tests.modbus import Client, crc16, read_holding
from tests.ops import status, tracing, tshark_warnings, wait_for, wait_for_log

pytestmark = pytest.mark.integration

STATIC = Path(__file__).resolve().parents[3] / "mbgw" / "web" / "static"
WAIT_S = 15
HOSTILE = "<img src=x onerror=window.__injected=1>"


@pytest.fixture(scope="module")
def browser():
    driver = start_chromium(1280, 900)
    yield driver
    driver.quit()


def wait(driver, condition, timeout: float = WAIT_S):
    """condition's value once true; an element the page's refresh replaced while it was read
    (stale) means: look again."""
    return WebDriverWait(driver, timeout,
                         ignored_exceptions=(StaleElementReferenceException,)).until(condition)


def text_in(selector: str, text: str):
    return EC.text_to_be_present_in_element((By.CSS_SELECTOR, selector), text)


def found(selector: str):
    return EC.presence_of_element_located((By.CSS_SELECTOR, selector))


# ---- a scripted API whose data carries markup --------------------------------------------

def hostile_documents() -> dict:
    client = {"id": 7, "peer": f"{HOSTILE}:5020", "connected_since": 1.7e9, "requests": 3,
              "in_flight": 0, "last_activity": 1.7e9, "listener": HOSTILE, "role": "plain"}
    scenario = {"name": HOSTILE, "kind": "serial", "target": "slave 1", "function": 3,
                "trigger": "1000 ms", "state": "error", "message": HOSTILE, "runs": 1,
                "successes": 0, "errors": {"timeout": 1}, "retries": 0, "overruns": 0,
                "last_success": None, "last_latency_ms": None, "data_age_s": None,
                "stale": False}
    status = {"mode": "slave", "version": HOSTILE, "uptime_s": 5, "started": 1.7e9,
              "serial": {"device": HOSTILE, "state": "up"}, "listening": [HOSTILE],
              "counters": {"requests": 1}, "clients": [client], "scenarios": [scenario],
              "devices": [], "table": {"persist": {"path": HOSTILE, "failing": HOSTILE,
                                                   "failing_since": 1.7e9}}}
    device = {"address": 15, "health": "down", "health_since": 1.7e9, "last_success": None,
              "consecutive_failures": 3, "transactions": 3, "diagnosis": HOSTILE}
    return {"/api/session": {"role": "admin", "csrf": "token"}, "/api/status": status,
            "/api/clients": {"clients": [client]}, "/api/scenarios": {"scenarios": [scenario]},
            "/api/devices": {"devices": [device]}}


TRACE_EVENT = {"time": 1.7e9, "direction": "request", "client": 7, "peer": HOSTILE,
               "remote": HOSTILE, "line": HOSTILE,
               "unit": 1, "function": 3, "length": 6, "pdu": HOSTILE, "outcome": HOSTILE}


def hostile_app() -> web.Application:
    documents = hostile_documents()

    async def page(request):
        path = STATIC / (request.match_info.get("name") or "index.html")
        if not path.is_file():
            raise web.HTTPNotFound()
        return web.FileResponse(path)

    async def document(request):
        return web.json_response(documents[request.path])

    async def trace(request):
        response = web.StreamResponse(headers={"Content-Type": "text/event-stream"})
        await response.prepare(request)
        for event in ({"mode": "slave"}, TRACE_EVENT):
            await response.write(f"data: {json.dumps(event)}\n\n".encode())
        await request.app["closing"].wait()      # open until the server stops
        return response

    app = web.Application()
    app["closing"] = asyncio.Event()
    app.router.add_get("/api/trace", trace)
    for path in documents:
        app.router.add_get(path, document)
    app.router.add_get("/", page)
    app.router.add_get("/static/{name}", page)
    return app


@pytest.fixture(scope="module")
def hostile_console():
    """The console's pages over the scripted API: the base URL."""
    port = free_port()
    loop = asyncio.new_event_loop()
    app = hostile_app()
    runner = web.AppRunner(app)
    loop.run_until_complete(runner.setup())
    loop.run_until_complete(web.TCPSite(runner, "127.0.0.1", port).start())
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{port}/"
    loop.call_soon_threadsafe(app["closing"].set)
    asyncio.run_coroutine_threadsafe(runner.cleanup(), loop).result(WAIT_S)
    loop.call_soon_threadsafe(loop.stop)
    thread.join(WAIT_S)


def assert_nothing_injected(driver):
    assert driver.find_elements(By.CSS_SELECTOR, "main img") == []
    assert driver.execute_script("return window.__injected") is None


def test_values_with_markup_are_shown_as_text(browser, hostile_console):
    browser.get(hostile_console + "#overview")
    wait(browser, text_in("#overview-facts", HOSTILE))          # version, device, listening
    wait(browser, text_in("#overview-wrong", "The exchange table is not kept since "))
    assert f": {HOSTILE}." in browser.find_element(By.ID, "overview-wrong").text
    assert_nothing_injected(browser)

    browser.get(hostile_console + "#clients")
    wait(browser, text_in("#clients-table td.peer", f"{HOSTILE}:5020"))
    assert_nothing_injected(browser)

    browser.get(hostile_console + "#scenarios")
    wait(browser, text_in("#scenarios-table td.name", HOSTILE))
    assert browser.find_element(By.CSS_SELECTOR, "#scenarios-table td.message").text == HOSTILE
    assert_nothing_injected(browser)

    browser.get(hostile_console + "#devices")              # why a device fails, under it
    wait(browser, text_in('#devices-table tr[data-address="15"] td.health-down .diagnosis',
                          HOSTILE))
    assert_nothing_injected(browser)

    browser.get(hostile_console + "#traffic")
    wait(browser, text_in("#trace-table td.pdu", HOSTILE))
    assert browser.find_element(By.CSS_SELECTOR, "#trace-table td.peer").text == HOSTILE
    assert_nothing_injected(browser)


# ---- a real gateway with its console -----------------------------------------------------

PASSWORDS = {"admin": "admin secret 1", "user": "user secret 2"}
TABLE_UNIT = 247                 # the exchange table's first unit (the default 247-254)
SCENARIO = "boiler"             # polls the pymodbus slave: running
LOST = "meter"                  # polls an address nothing answers: in error
GREEN, GREY, RED = "rgba(46, 157, 58, 1)", "rgba(158, 158, 158, 1)", "rgba(211, 47, 47, 1)"


def set_password(path: Path, role: str) -> None:
    done = subprocess.run([sys.executable, "-m", "mbgw", "config", "password", role, "--stdin",
                           "--config", str(path)],
                          input=PASSWORDS[role] + "\n", capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def console_file(path: Path, lines: list[str], roles=("admin",)) -> str:
    """Write the file: the console on a free port, then lines; a password for each of roles.
    The console's URL."""
    web_port = free_port()
    path.write_text("\n".join(["[web]", f'listen = "127.0.0.1:{web_port}"', *lines]) + "\n")
    for role in roles:
        set_password(path, role)
    return f"http://127.0.0.1:{web_port}/"


class Console:
    """`mbgw slave` with its console on, a pymodbus RTU slave on its line polled by one
    scenario (another polls an address nothing answers), and the configuration file it
    started from."""

    def __init__(self, directory: Path) -> None:
        self.pty = PtyPair(directory)
        self.peer = Peer("pymodbus_slave.py", self.pty.device, "1", "--silent-unknown")
        self.path = directory / "mbgw.toml"
        self.url = console_file(self.path, [
            "[serial]", 'mode = "slave"', "baudrate = 115200", "stout = 100",
            "[[scenario]]", f'name = "{SCENARIO}"', "slave = 1", "function = 3",
            "address = 0", "quantity = 2", "table = 0", "cycle = 200",
            "[[scenario]]", f'name = "{LOST}"', "slave = 9", "function = 3",
            "address = 0", "quantity = 2", "table = 10", "cycle = 1000"], PASSWORDS)
        self.gw = Gateway(directory, self.pty.gateway, "--config", str(self.path))

    def stop(self) -> None:
        self.gw.stop()
        self.peer.stop()
        self.pty.stop()


@pytest.fixture(scope="module")
def console(tmp_path_factory):
    running = Console(tmp_path_factory.mktemp("web"))
    yield running
    running.stop()


def log_in(driver, console, role: str, password: str | None = None) -> None:
    """A fresh session of role on the Overview (a wrong password: the login page stays)."""
    driver.get(console.url)
    driver.delete_all_cookies()
    driver.get(console.url + "#overview")
    wait(driver, EC.visibility_of_element_located((By.ID, "login-form")))
    Select(driver.find_element(By.ID, "login-user")).select_by_value(role)
    driver.find_element(By.ID, "login-password").send_keys(
        PASSWORDS[role] if password is None else password)
    driver.find_element(By.ID, "login-submit").click()
    if password is None:
        wait(driver, text_in("#role", role))


def go(driver, page: str) -> None:
    driver.find_element(By.CSS_SELECTOR, f'nav a[href="#{page}"]').click()
    wait(driver, EC.presence_of_element_located(
        (By.CSS_SELECTOR, f'#page-body[data-page="{page}"]')))


def scenario_state(driver, name: str):
    """(the state shown, its background colour) of a scenario's row, once it is shown."""
    row = f'#scenarios-table tr[data-key="serial/{name}"]'
    badge = wait(driver, found(f"{row} span.state"))
    return badge.text, badge.value_of_css_property("background-color")


def test_a_wrong_password_is_refused(browser, console):
    log_in(browser, console, "admin", "not the password")
    wait(browser, text_in("#login-error", "Wrong user or password"))
    assert not browser.find_element(By.ID, "nav").is_displayed()
    assert "web login failed for 'admin'" in wait_for_log(console.gw, "web login failed")


def test_a_session_gone_brings_back_the_login_and_log_out_ends_it(browser, console):
    log_in(browser, console, "admin")
    wait(browser, text_in('#overview-facts tr[data-name="Mode"] td', "slave"))
    browser.delete_cookie("mbgw_session")                # as when it expires
    wait(browser, text_in("#login-error", "The session has expired"))
    assert not browser.find_element(By.ID, "nav").is_displayed()
    log_in(browser, console, "user")
    cookie = browser.get_cookie("mbgw_session")
    browser.find_element(By.ID, "logout").click()
    wait(browser, text_in("#login-error", "Logged out"))
    browser.add_cookie({"name": cookie["name"], "value": cookie["value"]})
    browser.refresh()                                    # the server ended the session too
    wait(browser, EC.visibility_of_element_located((By.ID, "login-form")))
    assert not browser.find_element(By.ID, "nav").is_displayed()


def test_the_overview_shows_the_line_and_the_front_panel(browser, console):
    log_in(browser, console, "admin")
    wait(browser, text_in('#overview-facts tr[data-name="Mode"] td', "slave"))
    wait(browser, text_in('#overview-facts tr[data-name="Line state"] td', "up"))
    wait(browser, text_in('#overview-facts tr[data-name="Line load"] td', "% (1 min), "))
    assert " on average" in browser.find_element(
        By.CSS_SELECTOR, '#overview-facts tr[data-name="Line load"] td').text
    assert browser.find_element(By.ID, "led-line").get_attribute("data-state") == "green"
    shot = os.environ.get("MBGW_CONSOLE_SCREENSHOT")    # docs/console-overview.png is made so
    wait(browser, text_in("#overview-wrong", f"Scenario {LOST} is in error"))
    assert browser.find_element(By.ID, "led-scenarios").get_attribute("data-state") == "red"
    if shot:
        wait(browser, lambda d: d.find_element(By.ID, "led-devices")
             .get_attribute("data-state") == "red")
        browser.save_screenshot(shot)


def test_a_client_appears_and_the_admin_closes_it(browser, console):
    log_in(browser, console, "admin")
    go(browser, "clients")
    modbus = Client(console.gw.port)
    try:
        modbus.ask(TABLE_UNIT, read_holding(0, 1))
        here = "127.0.0.1:%d" % modbus.sock.getsockname()[1]
        row = wait(browser, lambda d: [r for r in d.find_elements(
            By.CSS_SELECTOR, "#clients-table tbody tr") if here in r.text])[0]
        row.find_element(By.CSS_SELECTOR, "button.close-client").click()
        wait(browser, EC.alert_is_present()).accept()      # Close asks first
        wait(browser, EC.staleness_of(row))
        modbus.sock.settimeout(WAIT_S)
        assert modbus.sock.recv(1) == b""            # the gateway closed the connection
    finally:
        modbus.close()


def test_a_disabled_scenario_turns_grey_and_green_again(browser, console):
    log_in(browser, console, "admin")
    go(browser, "scenarios")
    wait(browser, lambda d: scenario_state(d, SCENARIO) == ("running", GREEN))
    wait(browser, lambda d: scenario_state(d, LOST) == ("error", RED))
    # the message moves on once (a timeout, then "device down" when demotion skips its runs)
    wait(browser, lambda d: d.find_element(
        By.CSS_SELECTOR, f'#scenarios-table tr[data-key="serial/{LOST}"] td.message').text
        == scenarios(status(console.gw))[LOST]["message"] != "")
    row = browser.find_element(By.CSS_SELECTOR,
                               f'#scenarios-table tr[data-key="serial/{SCENARIO}"]')
    row.find_element(By.CSS_SELECTOR, "button.disable").click()
    wait(browser, lambda d: scenario_state(d, SCENARIO) == ("disabled", GREY))
    assert scenarios(status(console.gw))[SCENARIO]["state"] == "disabled"
    row.find_element(By.CSS_SELECTOR, "button.enable").click()
    wait(browser, lambda d: scenario_state(d, SCENARIO) == ("running", GREEN))


def test_a_register_written_in_the_browser_is_read_by_a_modbus_client(browser, console):
    log_in(browser, console, "admin")
    go(browser, "table")
    browser.find_element(By.ID, "table-write-address").send_keys("0x100")
    browser.find_element(By.ID, "table-write-values").send_keys("0x1234, 7")
    browser.find_element(By.ID, "table-write").click()
    wait(browser, text_in("#table-write-result", "written 2 from 0x0100"))
    with ModbusTcpClient("127.0.0.1", port=console.gw.port) as modbus:
        assert modbus.read_holding_registers(0x100, count=2, device_id=TABLE_UNIT).registers \
            == [0x1234, 7]
    address = browser.find_element(By.ID, "table-address")
    address.clear()
    address.send_keys("256")
    Select(browser.find_element(By.ID, "table-view")).select_by_value("hex")
    wait(browser, text_in('#table-grid tr[data-address="256"] td.value', "0x1234"))


def test_a_bad_setting_is_refused_next_to_its_field_and_a_good_one_applied(browser, console):
    log_in(browser, console, "admin")
    go(browser, "config")
    before = console.path.read_bytes()
    field = wait(browser, found('input[data-field="serial.stout"]'))
    field.clear()
    field.send_keys("soon")
    field.find_element(By.XPATH, "following-sibling::button").click()
    wait(browser, text_in('[data-error-for="serial.stout"]', "stout"))
    assert console.path.read_bytes() == before
    field.clear()
    field.send_keys("150")
    field.find_element(By.XPATH, "following-sibling::button").click()
    wait(browser, text_in('[data-error-for="serial.stout"]', "applied"))
    assert "stout = 150" in console.path.read_text()
    wait_for(console.gw, lambda s: s["serial"]["stout_ms"] == 150, "the new stout in force")


def test_an_upload_shows_what_the_daemon_did_with_it(browser, console, tmp_path):
    """The page waits for the reload and shows its outcome, the daemon's own log line: here
    a metrics address, which takes effect at restart."""
    log_in(browser, console, "admin")
    go(browser, "config")
    before = console.path.read_text()
    upload = tmp_path / "mbgw.toml"
    upload.write_text(before.replace("[web]\n", f'[general]\nmetrics = "127.0.0.1:{free_port()}"'
                                                 "\n[web]\n", 1))
    try:
        wait(browser, found("#config-upload-file")).send_keys(str(upload))
        browser.find_element(By.ID, "config-upload").click()
        line = ("configuration reloaded: nothing changed; not applied: metrics: takes effect "
                "at restart (systemctl restart mbgw)")
        wait(browser, text_in("#config-upload-result", f"written, but {line}"))
        assert console.gw.log().count(line) == 1
        assert console.path.read_text() == upload.read_text()
    finally:
        console.path.write_text(before)
        os.kill(console.gw.proc.pid, signal.SIGHUP)
        wait_for_log(console.gw, "configuration reloaded: nothing changed\n")


def test_the_user_role_changes_nothing(browser, console):
    log_in(browser, console, "user")
    for page, control in (("clients", None), ("scenarios", "button.disable"),
                          ("table", "#table-write"), ("stats", "#stats-reset"),
                          ("config", "button.config-save")):
        go(browser, page)
        if control:
            assert not wait(browser, found(control)).is_enabled()
    # the page's own controls forced open: the gateway refuses, and the page says so
    go(browser, "table")
    browser.execute_script("for (const e of document.querySelectorAll('.admin-only'))"
                           " e.disabled = false;")
    browser.find_element(By.ID, "table-write-address").send_keys("0x200")
    browser.find_element(By.ID, "table-write-values").send_keys("99")
    browser.find_element(By.ID, "table-write").click()
    wait(browser, text_in("#table-write-result", "refused"))
    go(browser, "scenarios")
    browser.execute_script("for (const e of document.querySelectorAll('.admin-only'))"
                           " e.disabled = false;")
    wait(browser, found("button.disable")).click()
    wait(browser, text_in("#scenarios-message", "refused"))
    assert scenarios(status(console.gw))[SCENARIO]["state"] != "disabled"
    with ModbusTcpClient("127.0.0.1", port=console.gw.port) as modbus:
        assert modbus.read_holding_registers(0x200, count=1, device_id=TABLE_UNIT).registers \
            == [0]


def test_the_pcap_of_the_shown_trace_is_the_one_mbgw_trace_writes(browser, console, tmp_path):
    log_in(browser, console, "admin")
    browser.execute_cdp_cmd("Page.setDownloadBehavior",
                            {"behavior": "allow", "downloadPath": str(tmp_path)})
    go(browser, "traffic")
    wait(browser, found('#trace-info[data-stream="open"]'))
    # the table's unit only: the scenarios' runs are traced too, but are no Modbus/TCP
    browser.find_element(By.ID, "trace-unit").send_keys(str(TABLE_UNIT))
    browser.find_element(By.ID, "trace-apply").click()
    wait(browser, found('#trace-info[data-stream="open"]'))
    reference = tmp_path / "reference.pcap"
    with tracing(console.gw, reference, 6, "--unit", str(TABLE_UNIT)) as (trace, _):
        modbus = Client(console.gw.port)
        try:
            for first in range(3):
                modbus.ask(TABLE_UNIT, read_holding(first, 2))
        finally:
            modbus.close()
        assert trace.wait(WAIT_S) == 0
    wait(browser, text_in("#trace-info", "6 events shown"))
    browser.find_element(By.ID, "trace-pcap").click()
    pcap = tmp_path / "mbgw-trace.pcap"
    wait(browser, lambda d: pcap.exists() and pcap.stat().st_size > 24)
    assert pcap.read_bytes() == reference.read_bytes()
    checked = tshark_warnings(pcap, console.gw.port)
    assert checked.returncode == 0 and checked.stdout == "", checked


def test_the_traffic_page_shows_scenario_runs_and_the_raw_line(browser, console):
    """The scenario's runs, marked with its name; then the raw line: the scenario's request
    with its CRC (tests/modbus.py's own) and the pymodbus slave's reply, each marked."""
    log_in(browser, console, "admin")
    go(browser, "traffic")
    wait(browser, text_in("#trace-table tbody", f"scenario {SCENARIO}"))
    browser.find_element(By.ID, "trace-raw").click()
    wait(browser, found('#trace-info[data-stream="open"]'))
    wait(browser, found("#trace-table tbody tr.raw-reply"))
    headings = [th.text for th in browser.find_elements(By.CSS_SELECTOR, "#trace-table th")]
    assert headings == ["Time", "Gap µs", "Kind", "Length", "Bytes"]
    rows = browser.find_elements(By.CSS_SELECTOR, "#trace-table tbody tr.raw-request td.bytes")
    requests = [bytes.fromhex(row.text) for row in rows]      # the other scenario's too
    request = bytes.fromhex("01 03 0000 0002")
    assert request + crc16(request) in requests, requests
    reply = browser.find_element(By.CSS_SELECTOR, "#trace-table tbody tr.raw-reply td.bytes")
    assert bytes.fromhex(reply.text)[:3] == bytes.fromhex("01 03 04")


def shown_rows(driver) -> list[list[str]]:
    """The Traffic page's visible rows, as their cells' text (read at once: rows come and
    go several times a second)."""
    return driver.execute_script(
        "return [...document.querySelectorAll('#trace-table tbody tr')]"
        ".filter((tr) => !tr.hidden).map((tr) => [...tr.cells].map((td) => td.textContent));")


def device_cells(driver, address: int) -> dict[str, str]:
    """The Devices page's row of address, each cell's text by each of its classes (read at
    once: the page rebuilds its rows at each refresh)."""
    return driver.execute_script(
        "return Object.fromEntries([...document.querySelectorAll("
        "`#devices-table tr[data-address=\"${arguments[0]}\"] td`)]"
        ".flatMap((td) => [...td.classList].map((c) => [c, td.textContent])));", address)


def trace_rows(driver) -> int:
    return driver.execute_script("return document.querySelectorAll('#trace-table tbody tr')"
                                 ".length;")


def test_the_traffic_page_filters_finds_and_pauses(browser, console):
    """Latencies in ms (not 6 decimals); the scenario filter of `mbgw trace`; the text
    filter of the rows shown; pause, which counts what it did not show."""
    log_in(browser, console, "admin")
    go(browser, "traffic")
    wait(browser, found('#trace-info[data-stream="open"]'))     # else the request may be missed
    modbus = Client(console.gw.port)
    try:
        here = "127.0.0.1:%d" % modbus.sock.getsockname()[1]
        modbus.ask(TABLE_UNIT, read_holding(0, 1))
        wait(browser, text_in("#trace-table tbody", here))         # every source at first
        browser.find_element(By.ID, "trace-scenario").send_keys(SCENARIO)
        browser.find_element(By.ID, "trace-apply").click()
        wait(browser, found('#trace-info[data-stream="open"]'))
        modbus.ask(TABLE_UNIT, read_holding(0, 1))
        rows = wait(browser, lambda d: len(shown_rows(d)) >= 10 and
                    [r for r in shown_rows(d) if r[1] == "reply"])
    finally:
        modbus.close()
    assert {r[3] for r in shown_rows(browser)} == {f"scenario {SCENARIO}"}
    assert re.fullmatch(r"\d+(\.\d{1,2})? ms", rows[0][-1]), rows[0]
    find = browser.find_element(By.ID, "trace-find")
    find.send_keys("request")                    # the rows shown with "request" only
    wait(browser, lambda d: shown_rows(d) and all(r[1] == "request" for r in shown_rows(d)))
    find.send_keys(Keys.CONTROL, "a")
    find.send_keys(Keys.BACKSPACE)               # typed away: every row again
    wait(browser, lambda d: {r[1] for r in shown_rows(d)} == {"request", "reply"})
    browser.find_element(By.ID, "trace-pause").click()
    count = trace_rows(browser)
    info = wait(browser, lambda d: re.search(r"paused \(([1-9]\d*) not shown\)",
                                             d.find_element(By.ID, "trace-info").text))
    assert int(info.group(1)) > 0
    assert trace_rows(browser) == count
    browser.find_element(By.ID, "trace-pause").click()          # Resume
    wait(browser, lambda d: trace_rows(d) > count)


def test_devices_statistics_and_a_scenario_test_from_the_browser(browser, console):
    log_in(browser, console, "admin")
    browser.get_log("browser")                           # only this test's entries below
    go(browser, "devices")
    wait(browser, found('#devices-table tr[data-address="1"] td.health-up'))
    wait(browser, found('#devices-table tr[data-address="9"] td.health-down'))
    # the demotion's timing (issue 29): one that never answered is probed with its line's
    # learnt time, between 20 ms and its stout (another test of this module may change stout)
    silent, answering = device_cells(browser, 9), device_cells(browser, 1)
    assert silent["learnt-p99"] == "—"
    stout = float(silent["stout"])
    assert stout == wait_for(console.gw, lambda s: True, "status")["serial"]["stout_ms"]
    assert 20 <= float(silent["probe-timeout"]) <= stout
    assert 0 < float(answering["learnt-p99"])
    assert 20 <= float(answering["probe-timeout"]) <= float(answering["stout"])
    go(browser, "stats")
    wait(browser, found('#stats-table tr[data-name="counters.requests"]'))
    go(browser, "scenarios")
    browser.find_element(By.ID, "scenario-test-fields").send_keys(
        "slave = 1\nfunction = 3\naddress = 0\nquantity = 2\ntable = 100")
    browser.find_element(By.ID, "scenario-test").click()
    wait(browser, text_in("#scenario-test-result", "answered in "))
    shown = browser.find_element(By.ID, "scenario-test-result")     # the values, not JSON
    assert "ok" in shown.get_attribute("class").split(), shown.text
    assert shown.text.endswith(" ms: 100, 101") and "{" not in shown.text, shown.text
    errors = [e for e in browser.get_log("browser") if e.get("source") == "javascript"]
    assert errors == []


PAGE_LOADED = {"clients": "#clients-table", "devices": "#devices-table, #no-devices",
               "scenarios": "#scenarios-table", "table": "#table-grid",
               "stats": "#stats-table", "traffic": '#trace-info[data-stream="open"]',
               "config": "#config-groups fieldset", "lines": "#lines-table, #no-lines"}


@pytest.mark.parametrize("mode", ["master", "transparent"])
def test_every_page_works_in_master_and_transparent_mode(browser, mode, tmp_path):
    path = tmp_path / "mbgw.toml"
    url = console_file(path, ["[serial]", f'mode = "{mode}"',
                              "[general]", 'location = "Pump house 3"'])
    pty = PtyPair(tmp_path)
    tcp_port = free_port()                      # the table's server, or transparent's
    options = ["--table", "--table-port", str(tcp_port)] if mode == "master" else \
        ["--bind", "127.0.0.1", "--mdbport", str(tcp_port)]
    gw = Gateway(tmp_path, pty.gateway, "--baudrate", "19200", "--config", str(path),
                 *options, mode=mode, listen=False)
    modbus = None
    try:
        modbus = Client(tcp_port)               # a client on Clients in every mode
        here = "127.0.0.1:%d" % modbus.sock.getsockname()[1]
        log_in(browser, SimpleNamespace(url=url), "admin")
        browser.get_log("browser")
        wait(browser, text_in('#overview-facts tr[data-name="Mode"] td', mode))
        wait(browser, text_in('#overview-facts tr[data-name="Location"] td', "Pump house 3"))
        device = browser.find_element(
            By.CSS_SELECTOR, '#overview-facts tr[data-name="Serial device"] td').text
        assert (" rtu " in device) == (mode == "master"), device  # transparent: no framing
        for page, loaded in PAGE_LOADED.items():
            go(browser, page)
            wait(browser, found(loaded))
            assert browser.find_element(By.ID, "page-error").text == "", page
            if page == "clients":
                wait(browser, text_in("#clients-table tbody", here))
        errors = [e for e in browser.get_log("browser") if e.get("source") == "javascript"]
        assert errors == []
    finally:
        if modbus is not None:
            modbus.close()
        gw.stop()
        pty.stop()


def scenarios(s: dict) -> dict:
    return {sc["name"]: sc for sc in s.get("scenarios", [])}


def test_the_lines_page_shows_every_line_and_each_remote_servers_figures(browser, tmp_path):
    path = tmp_path / "mbgw.toml"
    server_port = free_port()
    servers = Peer("pymodbus_tcp_servers.py", str(server_port), "127.0.0.1")
    pairs = {}
    for name in ("serial", "meters", "panel"):
        (tmp_path / name).mkdir()
        pairs[name] = PtyPair(tmp_path / name)
    meters, panel = pairs["meters"], pairs["panel"]
    url = console_file(path, [
        "[[line]]", 'name = "meters"', f'device = "{meters.gateway}"', "baudrate = 19200",
        "[[line]]", 'name = "panel"', f'device = "{panel.gateway}"', "baudrate = 19200",
        'mode = "master"',
        "[[route]]", 'units = "1-31"', 'line = "serial"',
        "[[route]]", 'units = "32-63"', 'line = "meters"', "offset = -31",
        "[[route]]", 'from = "panel"', 'units = "7"', 'line = "meters"', "address = 1",
        "[[route]]", 'units = "100-109"', f'server = "127.0.0.1:{server_port}"',
        "offset = -99"])
    gw = Gateway(tmp_path, pairs["serial"].gateway, "--baudrate", "19200", "--config", str(path))
    try:
        c = Client(gw.port)
        for start in range(3):
            assert c.ask(101, read_holding(start, 1)) == bytes((3, 2, 0, start))
        assert c.ask(101, read_holding(10, 1)) == b"\x83\x02"      # the server's exception
        log_in(browser, SimpleNamespace(url=url), "admin")
        browser.get_log("browser")
        go(browser, "lines")
        for line, mode in (("serial", "slave"), ("meters", "slave"), ("panel", "master")):
            row = f'#lines-table tr[data-line="{line}"]'
            wait(browser, found(row))
            cells = [td.text for td in browser.find_elements(By.CSS_SELECTOR, f"{row} td")]
            assert cells[:4] == [line, pairs[line].gateway, mode, "up"], cells
        server = f"127.0.0.1:{server_port}"
        row = f'#servers-table tr[data-server="{server}"]'
        wait(browser, found(row))
        cells = [td.text for td in browser.find_elements(By.CSS_SELECTOR, f"{row} td")]
        # Server, Requests, Replies, Exceptions, Timeouts, Unreachable, Open, Opened, Lost
        assert cells == [server, "4", "4", "1", "0", "0", "1", "1", "0"]
        errors = [e for e in browser.get_log("browser") if e.get("source") == "javascript"]
        assert errors == []
    finally:
        gw.stop()
        servers.stop()
        for pair in pairs.values():
            pair.stop()


def test_the_lines_page_shows_a_line_s_cache_figures(browser, tmp_path):
    path = tmp_path / "mbgw.toml"
    pair = PtyPair(tmp_path)
    peer = Peer("pymodbus_slave.py", pair.device, "1", "--silent-unknown")
    url = console_file(path, ["[serial]", "baudrate = 19200", "cache = { ttl = 600000 }"])
    gw = Gateway(tmp_path, pair.gateway, "--config", str(path))
    try:
        c = Client(gw.port)
        for _ in range(3):          # one miss, then two hits
            assert c.ask(1, read_holding(0, 2)) == bytes.fromhex("03 04 0064 0065")
        log_in(browser, SimpleNamespace(url=url), "admin")
        go(browser, "lines")
        # hits / coalesced / misses / stale
        wait(browser, text_in('#lines-table tr[data-line="serial"] td.cache', "2 / 0 / 1 / 0"))
        browser.get(url + "#lines/serial")   # the line's page, by unit
        row = '#line-page[data-line="serial"] #line-cache tr[data-unit="1"]'
        wait(browser, found(row))
        assert [td.text for td in browser.find_elements(By.CSS_SELECTOR, f"{row} td")] == \
            ["1", "2", "0", "1", "0"]
    finally:
        gw.stop()
        peer.stop()
        pair.stop()


def test_without_serial_the_pages_show_the_files_lines(browser, tmp_path):
    path = tmp_path / "mbgw.toml"
    server_port = free_port()
    servers = Peer("pymodbus_tcp_servers.py", str(server_port), "127.0.0.1")
    (tmp_path / "meters").mkdir()
    meters = PtyPair(tmp_path / "meters")
    inverter = f"modbus-tcp://127.0.0.1:{server_port}"
    url = console_file(path, [
        "[[line]]", 'name = "inverter"', f'connect = "{inverter}"',
        "[[line]]", 'name = "meters"', f'device = "{meters.gateway}"', "baudrate = 19200",
        "[[route]]", 'units = "1-10"', 'line = "inverter"',
        "[[route]]", 'units = "11-20"', 'line = "meters"', "offset = -10"])
    gw = Gateway(tmp_path, None, "--config", str(path))
    try:
        assert Client(gw.port).ask(3, read_holding(0, 3)) == bytes((3, 6, 0, 0, 0, 1, 0, 3))
        log_in(browser, SimpleNamespace(url=url), "admin")
        browser.get_log("browser")
        wait(browser, text_in('#overview-facts tr[data-name="Lines"] td', "inverter, meters"))
        wait(browser, text_in('#overview-facts tr[data-name="Line state"] td', "up"))
        go(browser, "lines")
        for line, device in (("inverter", inverter), ("meters", meters.gateway)):
            row = f'#lines-table tr[data-line="{line}"]'
            wait(browser, found(row))
            cells = [td.text for td in browser.find_elements(By.CSS_SELECTOR, f"{row} td")]
            assert cells[0] == line and cells[1].startswith(device) and cells[2:4] == \
                ["slave", "up"], cells
        assert browser.find_elements(By.CSS_SELECTOR, '#lines-table tr[data-line="serial"]') \
            == []
        errors = [e for e in browser.get_log("browser") if e.get("source") == "javascript"]
        assert errors == []
    finally:
        gw.stop()
        servers.stop()
        meters.stop()


def test_the_route_map_marks_the_implicit_routes(browser, console):
    """A file without [[route]]: today's routes, implicit, the table's units among them."""
    log_in(browser, console, "admin")
    go(browser, "lines")
    rows = wait(browser, lambda d: [[td.text for td in tr.find_elements(By.CSS_SELECTOR, "td")]
                                    for tr in d.find_elements(
                                        By.CSS_SELECTOR, "#routes-table tbody tr.implicit")])
    assert any(r[0] == "Modbus TCP" and str(TABLE_UNIT) in r[1] and "table" in r[2]
               and r[4] == "implicit" for r in rows), rows
    assert browser.find_elements(By.CSS_SELECTOR, "#routes-table tbody tr:not(.implicit)") \
        == []
