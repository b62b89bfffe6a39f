"""The settings: `model` holds the validated, frozen settings of slave and master mode with
every default and bound stated once, `transparent` transparent mode's, `scenario` and
`firewall` the [[scenario]] and [[rule]] tables', `number_list` the lists like '1,5,200-210';
`slaveid` the ACKSYS slaveid table.  The configuration file
(/etc/mbgw/mbgw.toml) is read and edited by `schema` (its keys, derived from the mode
commands' options, which the click group hands in: this package never imports mbgw.cli),
`values`, `file`, `edit` (the guide's `set` words), `text` and `toml_text` (comment-keeping
edits)."""
