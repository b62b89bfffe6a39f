"""The network pieces every listener and connection shares, whatever the mode: listening
sockets, addresses, authip, TLS and the logs kept to once a minute.

May import protocol, config, besides errors and audit.
See docs/architecture.md#the-packages.
"""
