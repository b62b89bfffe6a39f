"""docs/architecture.md names files, functions and C calls: each must exist, so that a rename
or a move that forgets the doc fails here instead of misleading the next reader."""
import ast
import re
from pathlib import Path

import pytest

from tests.unit.test_layout import ALLOWED

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "mbgw"
DOC = (ROOT / "docs" / "architecture.md").read_text()
SPANS = sorted(set(re.findall(r"`([^`\n]+)`", DOC)))


def _self_attributes(node: ast.AST) -> set[str]:
    """The names assigned as self.NAME anywhere under node."""
    found = set()
    for sub in ast.walk(node):
        targets = []
        if isinstance(sub, ast.Assign):
            targets = sub.targets
        elif isinstance(sub, (ast.AnnAssign, ast.AugAssign)):
            targets = [sub.target]
        for target in targets:
            if isinstance(target, ast.Attribute) and isinstance(target.value, ast.Name) \
                    and target.value.id == "self":
                found.add(target.attr)
    return found


def _defined(body: list[ast.stmt]) -> set[str]:
    """The names a module or class body defines (functions, classes, assignments, imports)."""
    names = set()
    for stmt in body:
        if isinstance(stmt, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(stmt.name)
        elif isinstance(stmt, ast.Assign):
            names |= {t.id for t in stmt.targets if isinstance(t, ast.Name)}
        elif isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name):
            names.add(stmt.target.id)
        elif isinstance(stmt, (ast.Import, ast.ImportFrom)):
            names |= {(a.asname or a.name).split(".")[0] for a in stmt.names}
    return names


def _index() -> tuple[dict[str, set[str]], dict[str, set[str]], dict[str, list[str]]]:
    """modules: "slave/router" -> its top-level names; classes: name -> attributes (merged
    over every class of that name); bases: class name -> its bases' names."""
    modules: dict[str, set[str]] = {}
    classes: dict[str, set[str]] = {}
    bases: dict[str, list[str]] = {}
    for path in PACKAGE.rglob("*.py"):
        tree = ast.parse(path.read_text(), str(path))
        modules[path.relative_to(PACKAGE).with_suffix("").as_posix()] = _defined(tree.body)
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                attrs = classes.setdefault(node.name, set())
                attrs |= _defined(node.body) | _self_attributes(node)
                bases.setdefault(node.name, []).extend(
                    b.id if isinstance(b, ast.Name) else
                    b.value.id if isinstance(b, ast.Subscript) and isinstance(b.value, ast.Name)
                    else "" for b in node.bases)
    return modules, classes, bases


MODULES, CLASSES, BASES = _index()
BASENAMES: dict[str, list[str]] = {}
for _module in MODULES:
    BASENAMES.setdefault(_module.rsplit("/", 1)[-1], []).append(_module)
# names of the OS and the libraries the doc names beside ours
EXTERNAL = {"MSG_PEEK", "SO_SNDTIMEO", "SO_TIMESTAMPNS", "SSLSocket", "VERIFY_CRL_CHECK_LEAF",
            "WATCHDOG_USEC"}
ALL_NAMES = set().union(*MODULES.values()) | EXTERNAL
PACKAGES = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()}
TOP_DIRS = {p.name for p in ROOT.iterdir() if p.is_dir() and not p.name.startswith(".")}
C_SOURCES = "\n".join(p.read_text() for p in (ROOT / "csrc").glob("*.[ch]"))


def class_has(name: str, attr: str) -> bool:
    seen: set[str] = set()
    todo = [name]
    while todo:
        cls = todo.pop()
        if cls in seen or cls not in CLASSES:
            continue
        seen.add(cls)
        if attr in CLASSES[cls]:
            return True
        todo.extend(BASES.get(cls, []))
    return False


def resolves(module: str, dotted: list[str]) -> bool:
    """module's name dotted[0], then each further name an attribute of that class."""
    first, rest = dotted[0], dotted[1:]
    if first not in MODULES[module]:
        return False
    if not rest:
        return True
    return len(rest) == 1 and class_has(first, rest[0])


def problem(span: str) -> str | None:
    """Why span, as the doc names it, names nothing in the tree (None: it is fine, or it is no
    name of ours)."""
    name = re.sub(r"\(.*\)$", "", span)
    if "/" in name and name.split("/")[0] in TOP_DIRS:     # a path from the repository's top
        return None if list(ROOT.glob(name.rstrip("/"))) else "no such path"
    if re.fullmatch(r"(\w+/)*\w+\.py", name):
        found = (PACKAGE / name).is_file() or "/" not in name and (ROOT / name).is_file()
        return None if found else "no such file"
    if re.fullmatch(r"mbgw_\w+", name):
        return None if re.search(rf"\b{name}\s*\(", C_SOURCES) else "no such C function"
    if (m := re.fullmatch(r"((?:\w+/)+\w+)\.(\w+(?:\.\w+)?)", name)) \
            and name.split("/")[0] in PACKAGES:
        module, dotted = m[1], m[2].split(".")
        if module not in MODULES:
            return f"no module mbgw/{module}.py"
        return None if resolves(module, dotted) else f"mbgw/{module}.py has no {m[2]}"
    if re.fullmatch(r"(\w+/)+\w*", name) and name.split("/")[0] in PACKAGES:
        known = name.rstrip("/") in MODULES or (PACKAGE / name).is_dir()
        return None if known else "no such module or package"
    if re.fullmatch(r"[A-Z]+[a-z]\w*|[A-Z][A-Z0-9]*_[A-Z0-9_]+", name):
        return None if name in ALL_NAMES else "no such class or constant in mbgw"
    if m := re.fullmatch(r"([A-Z]\w*)\.(\w+)", name):
        return None if class_has(m[1], m[2]) else f"no class {m[1]} with {m[2]}"
    if m := re.fullmatch(r"([a-z_]\w*)\.([A-Za-z_]\w*)", name):
        if m[1] not in BASENAMES or m[1] in PACKAGES:
            return None           # not a module of ours (a variable, a key, a package)
        owners = BASENAMES[m[1]]
        return None if any(resolves(o, [m[2]]) for o in owners) \
            else f"no module {m[1]} with {m[2]}"
    return None



def test_each_name_the_doc_gives_exists():
    assert len(SPANS) > 100, "the doc's names were not found"
    wrong = [f"`{span}`: {problem(span)}" for span in SPANS if problem(span) is not None]
    assert not wrong, "docs/architecture.md names what is not there:\n" + "\n".join(wrong)


def test_a_missing_name_is_caught():
    assert problem("slave/router.Router.nothing") is not None
    assert problem("slave/nothing.py") is not None
    assert problem("mbgw_nothing") is not None
    assert problem("Router.nothing") is not None
    assert problem("native.nothing") is not None
    assert problem("csrc/nothing.c") is not None
    assert problem("slave/nothing") is not None
    assert problem("mbgw/nothing/") is not None
    assert problem("slave/router.Router.request") is None
    assert problem("SlaveLineThread._lost") is None        # inherited from LineThread


COUNTS = re.findall(r"Count: \*\*(\d+)\*\* \(([^)]*)\)", DOC)


def test_each_path_says_its_count():
    assert len(COUNTS) >= 10, "a path without its count of Python files"


@pytest.mark.parametrize("count, files", COUNTS)
def test_each_count_is_its_list(count, files):
    assert int(count) == len(re.findall(r"`[^`]+`", files)), files


def anchor(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, no punctuation, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.lower()).replace(" ", "-")


ANCHORS = {anchor(h) for h in re.findall(r"^#+ (.+)$", DOC, re.M)}
INITS = sorted(p.parent.name for p in PACKAGE.glob("*/__init__.py"))


def test_a_heading_has_githubs_anchor():
    assert anchor("TCP face → line `serial`") == "tcp-face--line-serial"
    assert anchor("Details: serial faces (lines in master mode)") == \
        "details-serial-faces-lines-in-master-mode"


@pytest.mark.parametrize("package", INITS)
def test_each_package_says_its_job_imports_and_section(package):
    """A package's docstring: its job, what it may import (the layout test's rule, not a copy
    that drifts) and where the doc tells its part of a request's path."""
    doc = ast.get_docstring(ast.parse((PACKAGE / package / "__init__.py").read_text())) or ""
    links = re.findall(r"docs/architecture\.md#([\w-]+)", doc)
    assert links and set(links) <= ANCHORS, (links, sorted(ANCHORS))
    said = re.search(r"May import (.*?),\s+besides\s+errors\s+and\s+audit", doc, re.S)
    assert said, "no 'May import ..., besides errors and audit'"
    names = set(re.findall(r"[a-z]+", said[1].replace("the C core", "_ffi")))
    names -= {"and", "mbgw", "nothing"}
    names = {"_ffi" if n == "ffi" else n for n in names}
    assert names == ALLOWED[package] - {"errors", "audit"}, said[1]


def test_each_module_is_in_its_packages_list():
    """The package list is the tree: a module added, moved or renamed shows up here."""
    section = DOC[DOC.index("## The packages"):DOC.index("### The C core")]
    missing = []
    for path in sorted(PACKAGE.glob("*/*.py")):
        if path.name == "__init__.py":
            continue
        entry = re.search(rf"\*\*`{path.parent.name}/`\*\*(.*?)(?=\n- |\Z)", section, re.S)
        if entry is None or f"`{path.stem}`" not in entry[1]:
            missing.append(path.relative_to(PACKAGE).as_posix())
    assert not missing, f"docs/architecture.md, The packages, does not list {missing}"
