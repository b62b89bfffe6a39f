"""What the console's browser tests share: the desktop browser fixture (its home is
chrome.py, where a test of another folder imports it from)."""
from tests.integration.web.chrome import browser

__all__ = ["browser"]
