"""The settings (frozen, every default and bound stated once) and the configuration file
(/etc/mbgw/mbgw.toml), read and edited; never imports mbgw.cli (the click group hands the
mode commands in).

May import protocol, besides errors and audit.
See docs/architecture.md#the-packages.
"""
