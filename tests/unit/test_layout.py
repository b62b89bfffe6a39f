"""The layout's import rule: mbgw's packages import one way, and no module imports itself
back through others.  Read from the source (the AST), so a lazy import inside a function
counts as much as one at the top."""
import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "mbgw"

# what each part of mbgw may import besides itself; "mbgw" alone is the root (__version__);
# errors (the exception tree) and audit (the audit events' kinds) import nothing, so every
# part that refuses or changes something may name them
ALLOWED = {
    "protocol": {"errors", "audit"},
    "line": {"errors", "audit", "_ffi"},
    "config": {"protocol", "errors", "audit"},
    "net": {"protocol", "config", "errors", "audit"},
    "ops": {"net", "protocol", "config", "errors", "audit"},
    "firewall": {"net", "protocol", "config", "errors", "audit"},
    "table": {"net", "line", "protocol", "config", "errors", "audit", "_ffi", "firewall", "ops"},
    "upstream": {"net", "line", "ops", "protocol", "config", "errors", "audit"},
    "routing": {"ops", "protocol", "config", "errors", "audit"},
    "scenarios": {"table", "upstream", "line", "net", "ops", "protocol", "config", "errors",
                  "audit"},
    "slave": {"routing", "line", "table", "scenarios", "upstream", "net", "ops", "protocol",
              "config", "errors", "audit", "firewall", "web"},
    "master": {"routing", "line", "table", "scenarios", "upstream", "net", "ops", "protocol",
               "config", "errors", "audit", "firewall", "web"},
    "transparent": {"routing", "line", "table", "scenarios", "upstream", "net", "ops",
                    "protocol", "config", "errors", "audit", "firewall", "web"},
    "monitor": {"line", "table", "ops", "protocol", "config", "errors", "audit"},
    "web": {"net", "ops", "table", "scenarios", "config", "protocol", "errors", "audit"},
    "northbound": {"net", "ops", "table", "scenarios", "firewall", "config", "protocol",
                   "errors", "audit"},
    "gateway": {"routing", "slave", "master", "transparent", "scenarios", "upstream", "line",
                "monitor", "net", "table", "ops", "protocol", "config", "errors", "audit",
                "firewall", "web", "northbound"},
    "cli": {"gateway", "routing", "slave", "master", "transparent", "scenarios", "upstream", "line",
            "monitor", "net", "table", "ops", "protocol", "config", "errors", "audit", "firewall",
            "web", "northbound"},
    "__main__": {"cli"},
    "errors": set(),
    "audit": set(),
    "__init__": set(),
}


TYPE_CHECKING = ("TYPE_CHECKING", "typing.TYPE_CHECKING")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def imports(path: Path, known: set[str]) -> set[str]:
    """The mbgw modules that the file imports (a `from mbgw.pkg import mod` names the module
    when there is one, else the package), but not those imported for type annotations only
    (under `if TYPE_CHECKING:`)."""
    return imports_in(path.read_text(), str(path), known)


def imports_in(source: str, filename: str, known: set[str]) -> set[str]:
    found = set()
    tree = ast.parse(source, filename)
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and ast.unparse(node.test) in TYPE_CHECKING:
            node.body = []         # imports for annotations only: no dependency at run time
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.split(".")[0] == "mbgw"}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0 \
                and node.module.split(".")[0] == "mbgw":
            for alias in node.names:
                sub = f"{node.module}.{alias.name}"
                found.add(sub if sub in known else node.module)
    return found


def part(module: str) -> str:
    """mbgw.slave.server -> slave; mbgw.errors -> errors; mbgw -> __init__."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


GRAPH = {name: imports(path, set(modules()) | {"mbgw._ffi"}) for name, path in modules().items()}


def test_every_part_of_mbgw_has_a_rule():
    assert {part(m) for m in GRAPH} <= set(ALLOWED), {part(m) for m in GRAPH} - set(ALLOWED)


@pytest.mark.parametrize("module", sorted(GRAPH))
def test_imports_run_one_way(module):
    own = part(module)
    wrong = sorted(i for i in GRAPH[module]
                   if i != "mbgw" and part(i) != own and part(i) not in ALLOWED[own])
    assert not wrong, f"{module} ({own}) may not import {wrong}"


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components over the module graph: those of more than one
    module, each sorted (a module importing itself is no cycle Python trips on)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in graph:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for module in graph:
        if module not in index:
            visit(module)
    return found


def test_no_import_cycles():
    """No two modules import each other, directly or through others, at run time."""
    assert not cycles(GRAPH), cycles(GRAPH)


def test_a_cycle_through_modules_is_found():
    graph = {"a.x": {"a.y"}, "a.y": {"b.z"}, "b.z": {"a.x"}, "b.w": {"a.x"}, "c": {"c"}}
    assert cycles(graph) == [["a.x", "a.y", "b.z"]]
    assert cycles({"a.x": {"a.y"}, "a.y": set()}) == []


def test_imports_for_annotations_only_are_no_dependency():
    known = {"mbgw.config.model", "mbgw.config.firewall", "mbgw.config.slaveid",
             "mbgw.config.scenario"}
    source = (
        "import typing\n"
        "from typing import TYPE_CHECKING\n"
        "from mbgw.config.model import SerialConfig\n"
        "if TYPE_CHECKING:\n"
        "    from mbgw.config.firewall import FirewallConfig\n"
        "if typing.TYPE_CHECKING:\n"
        "    from mbgw.config import slaveid\n"
        "def lazy():\n"
        "    from mbgw.config import scenario\n")
    assert imports_in(source, "<test>", known) == {"mbgw.config.model", "mbgw.config.scenario"}


def test_only_the_line_and_the_table_import_the_c_core():
    users = sorted(m for m, deps in GRAPH.items() if "mbgw._ffi" in deps)
    assert users and all(part(m) in ("line", "table") for m in users), users


UNIT_TESTS = Path(__file__).resolve().parent


def test_each_folder_of_unit_tests_is_named_after_an_mbgw_package():
    """tests/unit/<name>/ holds the unit tests of mbgw/<name>/: a folder named after nothing
    (a typo, a package renamed or removed) would scatter the tests the layout keeps together."""
    packages = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()}
    folders = {p.name for p in UNIT_TESTS.iterdir() if p.is_dir() and p.name != "__pycache__"}
    assert folders, "no folder in tests/unit"
    assert folders <= packages, f"tests/unit/{sorted(folders - packages)} name no mbgw package"
