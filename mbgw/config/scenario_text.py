"""The `[[scenario]]` tables of the configuration file as text: adding one at the end,
taking one out by name (the rest of the file, comments included, untouched), and the
KEY=VALUE words of `mbgw config scenario add` and `mbgw scenario test`."""
import re
import tomllib

from mbgw.config.toml_text import dump_value
from mbgw.errors import ConfigError

HEADER = "[[scenario]]"
_SCENARIO_HEADER = re.compile(r"^\s*\[\[\s*scenario\s*\]\]\s*(#.*)?$")
_TABLE_START = re.compile(r"^\s*\[")


def parse_words(words) -> dict:
    """KEY=VALUE words -> {key: value}, a value typed as TOML would read it: a number, true or
    false, else the text (quotes around it are optional)."""
    fields: dict = {}
    for word in words:
        key, sep, text = word.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f"{word!r}: expected KEY=VALUE, e.g. function=3")
        if key in fields:
            raise ConfigError(f"{key}: given twice")
        fields[key] = _typed(text.strip())
    return fields


def _typed(text: str):
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    if re.fullmatch(r"[+-]?\d+", text):
        return int(text)
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "\"'":
        return text[1:-1]
    return text


def block(fields: dict) -> list[str]:
    return [HEADER, *(f"{key} = {dump_value(value)}" for key, value in fields.items())]


def add(text: str, fields: dict) -> str:
    """The text with one more [[scenario]] at its end."""
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    return "\n".join([*lines, *([""] if lines else []), *block(fields)]) + "\n"


def _blocks(lines: list[str]) -> list[tuple[int, int]]:
    """(first line, end line) of each [[scenario]] table."""
    found = []
    for index, line in enumerate(lines):
        if _SCENARIO_HEADER.match(line):
            end = next((i for i in range(index + 1, len(lines))
                        if _TABLE_START.match(lines[i])), len(lines))
            while end > index + 1 and (not lines[end - 1].strip()
                                       or lines[end - 1].lstrip().startswith("#")):
                end -= 1          # blank lines and comments before the next table are its own
            found.append((index, end))
    return found


def _named(lines: list[str], name: str) -> tuple[int, int] | None:
    """(first line, end line) of the first [[scenario]] table named `name` (one that is not
    valid TOML is passed over), None when there is none."""
    for first, end in _blocks(lines):
        try:
            content = tomllib.loads("\n".join(lines[first + 1:end]))
        except tomllib.TOMLDecodeError:
            continue
        if content.get("name") == name:
            return first, end
    return None


def remove(text: str, name: str) -> str | None:
    """The text without the [[scenario]] named `name`, None when it has none."""
    lines = text.splitlines()
    found = _named(lines, name)
    if found is None:
        return None
    first, end = found
    while end < len(lines) and not lines[end].strip():
        end += 1
    del lines[first:end]
    while lines and not lines[-1].strip():
        lines.pop()
    return "\n".join(lines) + "\n" if lines else ""


def set_enabled(text: str, name: str, on: bool) -> str | None:
    """The text with scenario `name` enabled (its `enabled` key taken out: true is the
    default) or disabled (`enabled = false`), None when it has no such scenario."""
    lines = text.splitlines()
    found = _named(lines, name)
    if found is None:
        return None
    first, end = found
    keep = [line for line in lines[first + 1:end] if not re.match(r"^\s*enabled\s*=", line)]
    if not on:
        keep.append("enabled = false")
    lines[first + 1:end] = keep
    return "\n".join(lines) + "\n"
