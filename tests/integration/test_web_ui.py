"""The web console's pages in a real browser: Debian's chromium, headless, driven through
chromium-driver by selenium.  One browser for the module; waits are WebDriverWait conditions.

The escaping test serves the pages with a scripted API (a small aiohttp server of canned
documents whose strings carry markup: a gateway cannot be made to send those); the others run
against a real `mbgw slave` with its console on."""
import asyncio
import json
import os
import shutil
import threading
from pathlib import Path

import pytest

webdriver = pytest.importorskip("selenium.webdriver")
from aiohttp import web  # noqa: E402
from selenium.webdriver.chrome.service import Service  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.support import expected_conditions as EC  # noqa: E402
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402

from tests.harness import free_port  # noqa: E402

pytestmark = pytest.mark.integration

STATIC = Path(__file__).resolve().parents[2] / "mbgw" / "web" / "static"
WAIT_S = 15
HOSTILE = "<img src=x onerror=window.__injected=1>"
CHROMIUM = shutil.which("chromium")
DRIVER = shutil.which("chromedriver")


@pytest.fixture(scope="module")
def browser():
    if not (CHROMIUM and DRIVER):
        pytest.skip("chromium and chromium-driver are not installed (scripts/setup.sh)")
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in ("--headless=new", "--disable-gpu", "--disable-dev-shm-usage",
                 "--window-size=1280,900"):
        options.add_argument(flag)
    if os.geteuid() == 0:
        options.add_argument("--no-sandbox")       # chromium refuses to run as root without
    driver = webdriver.Chrome(service=Service(DRIVER), options=options)
    yield driver
    driver.quit()


def wait(driver, condition, timeout: float = WAIT_S):
    return WebDriverWait(driver, timeout).until(condition)


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
              "devices": []}
    return {"/api/session": {"role": "admin", "csrf": "token"}, "/api/status": status,
            "/api/clients": {"clients": [client]}, "/api/scenarios": {"scenarios": [scenario]}}


TRACE_EVENT = {"time": 1.7e9, "direction": "request", "client": 7, "peer": HOSTILE,
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
    app.router.add_get("/{name}", page)
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
    assert_nothing_injected(browser)

    browser.get(hostile_console + "#clients")
    wait(browser, text_in("#clients-table td.peer", f"{HOSTILE}:5020"))
    assert_nothing_injected(browser)

    browser.get(hostile_console + "#scenarios")
    wait(browser, text_in("#scenarios-table td.name", HOSTILE))
    assert browser.find_element(By.CSS_SELECTOR, "#scenarios-table td.message").text == HOSTILE
    assert_nothing_injected(browser)

    browser.get(hostile_console + "#traffic")
    wait(browser, text_in("#trace-table td.pdu", HOSTILE))
    assert browser.find_element(By.CSS_SELECTOR, "#trace-table td.peer").text == HOSTILE
    assert_nothing_injected(browser)
