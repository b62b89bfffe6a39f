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
    "line": {"protocol", "errors", "audit", "_ffi"},
    "config": {"protocol", "errors", "audit"},
    "net": {"protocol", "config", "errors", "audit"},
    "ops": {"net", "protocol", "config", "errors", "audit"},
    "firewall": {"net", "protocol", "config", "errors", "audit"},
    "table": {"net", "protocol", "config", "errors", "audit", "_ffi", "firewall", "ops"},
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
    "web": {"net", "ops", "table", "scenarios", "config", "protocol", "errors", "audit"},
    "gateway": {"routing", "slave", "master", "transparent", "scenarios", "upstream", "line",
                "net", "table", "ops", "protocol", "config", "errors", "audit", "firewall", "web"},
    "cli": {"gateway", "routing", "slave", "master", "transparent", "scenarios", "upstream", "line",
            "net", "table", "ops", "protocol", "config", "errors", "audit", "firewall", "web"},
    "__main__": {"cli"},
    "errors": set(),
    "audit": set(),
    "__init__": set(),
}


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
    found = set()
    tree = ast.parse(path.read_text(), str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and ast.unparse(node.test) == "TYPE_CHECKING":
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


def test_no_import_cycles():
    """Tarjan's strongly connected components over the module graph: every one a single
    module that does not import itself."""
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in GRAPH.get(v, ()):
            if w not in GRAPH:
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
                cycles.append(sorted(component))

    for module in GRAPH:
        if module not in index:
            visit(module)
    assert not cycles, cycles


def test_only_the_line_and_the_table_import_the_c_core():
    users = sorted(m for m, deps in GRAPH.items() if "mbgw._ffi" in deps)
    assert users and all(part(m) in ("line", "table") for m in users), users
