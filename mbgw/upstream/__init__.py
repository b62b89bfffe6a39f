"""Modbus TCP connections to remote servers (`pool.UpstreamPool`), on the thread of its owner:
a serial face, the servers' thread of the TCP face, the TCP scenarios.

May import net, line, ops, protocol, config, besides errors and audit.
See docs/architecture.md#serial-face--remote-server.
"""
