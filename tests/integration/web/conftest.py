"""What the console's browser tests share."""
import pytest

from tests.integration.web.chrome import DESKTOP, start_chromium


@pytest.fixture(scope="module")
def browser():
    """Chromium at desktop size, shared by the tests of a module (one that wants another
    size defines its own)."""
    driver = start_chromium(*DESKTOP)
    yield driver
    driver.quit()
