"""The console's changes done through its pages, each seen from outside: several settings
applied by one reload."""
import pytest
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import Select

from tests.integration.web.chrome import DESKTOP, start_chromium
from tests.integration.web.test_web_ui import Console, found, go, log_in, text_in, wait
from tests.ops import wait_for, wait_for_log

pytestmark = pytest.mark.integration

RELOADED = "configuration reloaded: "


@pytest.fixture(scope="module")
def console(tmp_path_factory):
    running = Console(tmp_path_factory.mktemp("admin"))
    yield running
    running.stop()


@pytest.fixture(scope="module")
def browser():
    driver = start_chromium(*DESKTOP)
    yield driver
    driver.quit()


def field(browser, name: str):
    return wait(browser, found(f'[data-field="{name}"]'))


def test_several_settings_are_applied_by_one_reload(browser, console):
    log_in(browser, console, "admin")
    go(browser, "config")
    reloads = console.gw.log().count(RELOADED)
    stout = field(browser, "serial.stout")
    stout.clear()
    stout.send_keys("250")
    retries = field(browser, "serial.retries")
    retries.clear()
    retries.send_keys("2")
    exception = Select(field(browser, "net.exception"))
    flipped = {"on": "off", "off": "on"}[exception.first_selected_option.text]
    exception.select_by_value(flipped)
    browser.find_element(By.ID, "config-apply").click()
    wait(browser, text_in("#config-apply-result", "applied by one reload"))
    text = console.path.read_text()
    assert "stout = 250" in text and "retries = 2" in text
    assert f"exception = {'true' if flipped == 'on' else 'false'}" in text
    s = wait_for(console.gw, lambda s: s["serial"]["stout_ms"] == 250, "the new stout")
    assert console.gw.log().count(RELOADED) == reloads + 1, console.gw.log()
    assert s["serial"]["stout_ms"] == 250


def test_one_bad_setting_refuses_them_all_next_to_its_field(browser, console):
    log_in(browser, console, "admin")
    go(browser, "config")
    before = console.path.read_bytes()
    reloads = console.gw.log().count(RELOADED)
    stout = field(browser, "serial.stout")
    stout.clear()
    stout.send_keys("300")
    retries = field(browser, "serial.retries")
    retries.clear()
    retries.send_keys("many")
    browser.find_element(By.ID, "config-apply").click()
    wait(browser, text_in('[data-error-for="serial.retries"]', "retries"))
    assert "error" in browser.find_element(By.ID, "config-apply-result").get_attribute("class")
    assert console.path.read_bytes() == before
    assert console.gw.log().count(RELOADED) == reloads


def test_groups_of_other_modes_are_hidden_and_keys_have_help_units_and_choices(browser,
                                                                              console):
    log_in(browser, console, "admin")
    go(browser, "config")
    wait(browser, found('fieldset[data-group="serial"]'))
    groups = [f.get_attribute("data-group")
              for f in browser.find_elements(By.CSS_SELECTOR, "#config-groups fieldset")]
    assert "transparent" not in groups and "serial" in groups, groups
    assert browser.find_elements(By.CSS_SELECTOR, '[data-field="table.address"]') == []
    row = browser.find_element(By.CSS_SELECTOR, '.config-row[data-key="serial.stout"]')
    assert row.find_element(By.CSS_SELECTOR, ".unit").text == "ms"
    assert "end of its answer" in row.find_element(By.CSS_SELECTOR, ".help").text
    choices = [o.get_attribute("value") for o in
               Select(field(browser, "serial.format")).options]
    assert "8n1" in choices and "7e1" in choices
    assert Select(field(browser, "serial.protocol")).first_selected_option.text == "rtu"
    wait_for_log(console.gw, "web login")
