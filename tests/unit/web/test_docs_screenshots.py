"""The console's screenshots in docs/ (issue 30: two of every page's, kept by the browser
tests in artifacts/console/): each shown by the README or docs/console.md, each there, and
each at a width the pages are tested at."""
import re
import struct
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
TESTED_WIDTHS = {1280, 390}             # tests/integration/web/chrome.py: DESKTOP, PHONE


def png_size(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR", path
    width, height = struct.unpack(">II", head[16:24])
    return width, height


def shown() -> set[str]:
    text = (ROOT / "README.md").read_text() + (ROOT / "docs" / "console.md").read_text()
    return set(re.findall(r"\]\((docs/console-[\w-]+\.png)\)", text))


def test_every_screenshot_in_docs_is_shown_and_every_one_shown_is_there():
    kept = {str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("console-*.png")}
    assert len(kept) >= 2
    assert shown() == kept


def test_each_is_a_page_at_a_tested_width():
    for name in shown():
        width, height = png_size(ROOT / name)
        assert width in TESTED_WIDTHS and height >= 800, (name, width, height)
