"""Editing a small flat TOML file as text, so that its comments and layout survive: the value
of one key changes in place, a commented-out "# key = ..." line is taken up, or the key is added
at the end of its table.  And writing it atomically."""
import dataclasses
import errno
import json
import os
import re
import stat
import tempfile
import tomllib
from pathlib import Path

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def dumpable(value) -> bool:
    return isinstance(value, (bool, int, float, str)) or (
        isinstance(value, (list, tuple)) and all(dumpable(v) for v in value)) or (
        isinstance(value, dict) and all(isinstance(k, str) and _BARE_KEY.fullmatch(k)
                                        and dumpable(v) for k, v in value.items()))


def dump_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(dump_value(v) for v in value) + "]"
    if isinstance(value, dict) and dumpable(value):     # an inline table (`cache`)
        return "{ " + ", ".join(f"{k} = {dump_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"cannot write {value!r} in TOML")


_HEADER = re.compile(r"^\s*\[\s*([A-Za-z0-9_-]+)\s*\]\s*(#.*)?$")
_TABLE_START = re.compile(r"^\s*\[")
_KEY_LINE = re.compile(r"""^\s*(?:"([^"]*)"|'([^']*)'|([A-Za-z0-9_-]+))\s*[.=]""")
_COMMENTED_KEY = re.compile(r"^\s*#\s*([A-Za-z0-9_-]+)\s*=")


@dataclasses.dataclass
class _Section:
    name: str | None           # None: before the first table header
    header: int                # line index of the header (-1 for the top)
    end: int                   # index after its last line
    keys: dict                 # key -> (first line, end line) of its value
    commented: dict            # key -> line of "# key = ..."
    last_content: int          # last line holding a key or a header


def _value_end(lines: list[str], start: int) -> int:
    """The line after the value starting at `start` (arrays and strings may span lines)."""
    for end in range(start + 1, len(lines) + 1):
        try:
            tomllib.loads("\n".join(lines[start:end]))
            return end
        except tomllib.TOMLDecodeError:
            continue
    return start + 1


def _scan(lines: list[str]) -> list[_Section]:
    sections = [_Section(None, -1, len(lines), {}, {}, -1)]
    index = 0
    while index < len(lines):
        line = lines[index]
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            match = _COMMENTED_KEY.match(line)
            if match:
                sections[-1].commented.setdefault(match[1], index)
            index += 1
        elif _TABLE_START.match(line):
            sections[-1].end = index
            match = _HEADER.match(line)
            sections.append(_Section(match[1] if match else line.strip(), index, len(lines),
                                     {}, {}, index))
            index += 1
        else:
            end = _value_end(lines, index)
            match = _KEY_LINE.match(line)
            if match:
                sections[-1].keys[next(g for g in match.groups() if g is not None)] = (index, end)
            sections[-1].last_content = end - 1
            index = end
    return sections


def _inline_comment(lines: list[str]) -> str:
    """A trailing '# ...' after a value, to keep when the value changes."""
    whole = tomllib.loads("\n".join(lines))
    last = lines[-1]
    for position in (i for i, c in enumerate(last) if c == "#"):
        try:
            if tomllib.loads("\n".join([*lines[:-1], last[:position]])) == whole:
                return "  " + last[position:].rstrip()
        except tomllib.TOMLDecodeError:
            continue
    return ""


def set_line(text: str, table: str, name: str, new_line: str | None,
             commented_default: str | None = None) -> str:
    """The text with key `name` of [table] written as `new_line` ("key = value"), or taken out
    when new_line is None (a `commented_default` line takes its place).  Comments and layout
    are kept: the value changes in place, else a "# key = ..." line of the table is taken up,
    else the key goes at the end of its table, else the table at the end of the text."""
    lines = text.splitlines()
    section = next((s for s in _scan(lines) if s.name == table), None)
    if section is not None and name in section.keys:
        start, end = section.keys[name]
        indent = _indent(lines[start])
        if new_line is None:
            lines[start:end] = [indent + commented_default] if commented_default else []
        else:
            lines[start:end] = [indent + new_line + _inline_comment(lines[start:end])]
    elif new_line is None:
        return text
    elif section is not None and name in section.commented:
        index = section.commented[name]
        lines[index] = _indent(lines[index]) + new_line
    elif section is not None:
        lines.insert(section.last_content + 1, new_line)
    else:
        while lines and not lines[-1].strip():
            lines.pop()
        lines += ["", f"[{table}]", new_line] if lines else [f"[{table}]", new_line]
    return "\n".join(lines) + "\n"


def write_atomic(path: Path, text: str) -> None:
    """Replace `path` by `text` so that a reader sees the old file or the new one, never a part:
    a temporary file in the same directory, fsync, rename over, fsync the directory.  The file
    keeps its mode and owner (a new one is 0644: the service user reads it).  Raises OSError
    (PermissionError when not allowed to write there)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        old = os.stat(path)
    except FileNotFoundError:
        old = None
    if old is not None and not stat.S_ISREG(old.st_mode):
        raise OSError(errno.EINVAL, "not a regular file", str(path))
    fd, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as stream:
            stream.write(text)
            stream.flush()
            os.fchmod(stream.fileno(), stat.S_IMODE(old.st_mode) if old else 0o644)
            if old and (old.st_uid, old.st_gid) != (os.geteuid(), os.getegid()):
                try:
                    os.fchown(stream.fileno(), old.st_uid, old.st_gid)
                except PermissionError:
                    pass
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:
        try:
            os.unlink(temporary)
        except FileNotFoundError:
            pass
        raise
    directory = os.open(path.parent, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(directory)
    finally:
        os.close(directory)


def _indent(line: str) -> str:
    return line[:len(line) - len(line.lstrip())]
