"""Debian's chromium, headless, driven through chromium-driver by selenium: one window of a
given size (the console is tested at a desktop's 1280×800 and a phone's 390×844)."""
import os
import shutil

from selenium import webdriver
from selenium.webdriver.chrome.service import Service

CHROMIUM = shutil.which("chromium")
DRIVER = shutil.which("chromedriver")
DESKTOP = (1280, 800)
PHONE = (390, 844)


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
    driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", {
        "width": width, "height": height, "deviceScaleFactor": 1, "mobile": width < 600})
    return driver
