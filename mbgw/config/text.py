"""The text of the configuration file: the factory-default file (every key with its help,
commented out at its built-in default) and edits of the text that keep its comments."""
import textwrap

import click

from mbgw.config.edit import REMOVE
from mbgw.config.schema import (
    AUTHIP_ENTRIES,
    FACTORY_DEVICE,
    GROUPS,
    MODE_KEY,
    NO_ADDRESS,
    Schema,
    default_value,
)
from mbgw.config.toml_text import dump_value, set_line


def default_line(schema: Schema, name: str, mode: str) -> str:
    """The commented-out line showing a key's built-in default."""
    value = default_value(schema, name, mode)
    written = schema.file_name(name)
    return f"# {written} =" if value is None else f"# {written} = {dump_value(value)}"


_NOTES = {
    MODE_KEY: ["slave: Modbus slaves on the serial line, reached by Modbus TCP clients; master: "
               "a Modbus master on the line, reaching Modbus TCP servers. Also 'mbgw config "
               "set serial mode rtu|ascii' sets the protocol. Changing the mode clears the "
               "net.authip and net.slaveid tables."],
    "authip": [f"Set with: mbgw config set net authip N IP (entry N 1..{AUTHIP_ENTRIES}; "
               f"{NO_ADDRESS} clears it). The entries are the list items in order."],
    "slaveid": ["Set with: mbgw config set net slaveid SA (slave mode), or ... slaveid FS LS "
                "FR M IP once per range (master mode; FS 0 clears the table)."],
}


def _describe(schema: Schema, name: str) -> list[str]:
    """The help of a key's option(s), as comment lines; "(slave mode) ..." where the modes'
    options differ or only one mode has it."""
    lines = []
    if name != MODE_KEY:
        key = schema.keys[name]
        texts = {}
        for mode, param in key.params.items():
            text = param.help or ""
            if isinstance(param.type, click.Choice):
                text += f" One of: {', '.join(map(str, param.type.choices))}."
            texts[mode] = text.strip()
        if len(key.params) == len(schema.modes) and len(set(texts.values())) == 1:
            lines.append(texts[schema.modes[0]])
        else:
            lines += [f"({mode} mode) {text}" for mode, text in texts.items()]
    if name != "slaveid" or "master" in schema.modes:
        lines += _NOTES.get(name, [])
    return [c for text in lines if text for c in textwrap.wrap(
        text, 92, initial_indent="# ", subsequent_indent="# ")]


def factory_text(schema: Schema) -> str:
    """The factory-default file: every key with its help, commented out at its built-in
    default, except mode and device (the device has no built-in default)."""
    mode = schema.default_mode
    out = ["# mbgw configuration: one gateway, one serial line. The keys are the options of",
           "# 'mbgw slave|master|transparent --help' (the ACKSYS command names); the",
           "# command line wins over this file, and a key left out or commented out takes the",
           "# built-in default shown.",
           "#   mbgw config show                  the effective settings",
           "#   mbgw config set serial stout 700  change one (checked, written atomically)",
           "#   mbgw check-config                 check this file",
           "#   systemctl reload mbgw             apply it to the running service"]
    for group in GROUPS:
        names = schema.group_keys(group)
        if not names:
            continue
        out += ["", f"[{group}]"]
        for name in names:
            out += ["", *_describe(schema, name)]
            if name == MODE_KEY:
                out.append(f"{MODE_KEY} = {dump_value(mode)}")
            elif name == "device":
                out.append(f"device = {dump_value(FACTORY_DEVICE)}")
            else:
                out.append(default_line(schema, name, mode))
    return "\n".join(out) + "\n"


def edit(text: str, schema: Schema, mode: str, changes: dict) -> str:
    """Apply {key: value or REMOVE} to the file text (see set_line)."""
    for name, value in changes.items():
        group, written = schema.place(name)
        if value is REMOVE:
            text = set_line(text, group, written, None,
                            None if name == MODE_KEY else default_line(schema, name, mode))
        else:
            text = set_line(text, group, written, f"{written} = {dump_value(value)}")
    return text

