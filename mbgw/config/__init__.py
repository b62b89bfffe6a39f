"""The settings: `model` holds the validated, frozen settings of both modes with every default
and bound stated once; `slaveid` the ACKSYS slaveid table.  The configuration file
(/etc/mbgw/mbgw.toml) is read and edited by `schema` (its keys, derived from the mode
commands' options, which the click group hands in: this package never imports mbgw.cli),
`values`, `file`, `edit` (the guide's `set` words), `text` and `toml_text` (comment-keeping
edits)."""
