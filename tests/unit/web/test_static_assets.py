"""The console's front end (issue 30): ES modules loaded as they are, no build step, no
outside asset (a plant has no internet), one module per page of the navigation bar, every
module named by docs/console.md and every page by the README."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
STATIC = ROOT / "mbgw" / "web" / "static"
IMPORT = re.compile(r'^import [^;]*? from "([^"]+)";', re.M | re.S)
URL = re.compile(r"""(?:src|href)\s*=\s*["']([^"']+)["']|url\(\s*["']?([^"')]+)""")


def modules() -> list[Path]:
    return sorted(STATIC.glob("*.js"))


def test_every_import_is_a_module_of_the_package():
    for module in modules():
        for name in IMPORT.findall(module.read_text()):
            assert re.fullmatch(r"\./[a-z_]+\.js", name), (module.name, name)
            assert (STATIC / name[2:]).is_file(), (module.name, name)


def test_no_page_or_style_loads_anything_from_outside():
    for path in [STATIC / "index.html", STATIC / "console.css", *modules()]:
        text = path.read_text()
        assert "http://" not in text and "https://" not in text, path.name
        for found in URL.findall(text):
            url = found[0] or found[1]
            assert url.startswith(("/", "#", "./", "data:")) or "${" in url, (path.name, url)


def test_docs_console_md_names_every_module():
    doc = (ROOT / "docs" / "console.md").read_text()
    missing = [m.name for m in modules() if f"`{m.name}`" not in doc]
    assert missing == []


def test_the_readme_lists_every_page_of_the_navigation_bar():
    nav = re.findall(r'<a href="#(\w+)">([^<]+)</a>', (STATIC / "index.html").read_text())
    readme = (ROOT / "README.md").read_text()
    pages = readme[readme.index("### The pages"):readme.index("### The JSON API")]
    listed = re.findall(r"^- \*\*([^*]+)\*\*", pages, re.M)
    assert listed == [label for _, label in nav]
    assert [name for name, _ in nav if not (STATIC / f"{name}.js").is_file()] == []  # one each
