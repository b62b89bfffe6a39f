"""An array of tables of the configuration file (`[[rule]]`, ...) replaced as text: every
table of that name taken out, the new ones written at the end in order; the rest of the file,
comments included, untouched."""
import re

from mbgw.config.toml_text import dump_value

_TABLE_START = re.compile(r"^\s*\[")


def _header(name: str) -> re.Pattern:
    return re.compile(rf"^\s*\[\[\s*{re.escape(name)}\s*\]\]\s*(#.*)?$")


def replace_tables(text: str, name: str, tables: list[dict]) -> str:
    header = _header(name)
    lines = text.splitlines()
    kept: list[str] = []
    inside = False
    for line in lines:
        if header.match(line):
            inside = True
            continue
        if inside and _TABLE_START.match(line):
            inside = False
        if not inside:
            kept.append(line)
    while kept and not kept[-1].strip():
        kept.pop()
    for table in tables:
        kept += ["", f"[[{name}]]", *(f"{key} = {dump_value(value)}"
                                      for key, value in table.items())]
    return "\n".join(kept).lstrip("\n") + "\n"
