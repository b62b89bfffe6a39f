"""Debian's chromium, headless, driven through chromium-driver by selenium: one window of a
given size (the console is tested at a desktop's 1280×800 and a phone's 390×844), and
whether a page fits it."""
import contextlib
import os
import shutil
from pathlib import Path

import pytest
from selenium import webdriver
from selenium.webdriver.chrome.service import Service

CHROMIUM = shutil.which("chromium")
DRIVER = shutil.which("chromedriver")
DESKTOP = (1280, 800)
PHONE = (390, 844)
ARTIFACTS = Path(__file__).resolve().parents[3] / "artifacts" / "console"

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


def start_chromium(width: int, height: int) -> webdriver.Chrome:
    assert CHROMIUM and DRIVER, "chromium and chromium-driver: scripts/setup.sh installs them"
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in ("--headless=new", "--disable-gpu", "--disable-dev-shm-usage",
                 f"--window-size={width},{height}"):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})    # script errors
    if os.geteuid() == 0:
        options.add_argument("--no-sandbox")       # chromium refuses to run as root without
    driver = webdriver.Chrome(service=Service(DRIVER), options=options)
    # --window-size is the window's, not the page's: the page gets exactly width × height
    size_page(driver, (width, height))
    return driver


@pytest.fixture(scope="module")
def browser():
    """Chromium at desktop size, shared by the tests of a module (one that wants another
    size defines its own)."""
    driver = start_chromium(*DESKTOP)
    yield driver
    driver.quit()


def size_page(driver: webdriver.Chrome, size: tuple[int, int]) -> None:
    width, height = size
    driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", {
        "width": width, "height": height, "deviceScaleFactor": 1, "mobile": width < 600})


@contextlib.contextmanager
def page_of_size(driver: webdriver.Chrome, size: tuple[int, int]):
    """The page at size for the block, at the desktop's again after it."""
    size_page(driver, size)
    try:
        yield
    finally:
        size_page(driver, DESKTOP)


def assert_fits(driver: webdriver.Chrome, shot: str) -> None:
    """The page as it is now is no wider than the window and has every button in reach; its
    screenshot kept as artifacts/console/SHOT.png either way."""
    shown, window, unreachable = driver.execute_script(MEASURE)
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    driver.save_screenshot(str(ARTIFACTS / f"{shot}.png"))
    assert shown <= window, f"{shot}: {shown} px wide in {window}"
    assert unreachable == [], f"{shot}: {unreachable} out of reach"
