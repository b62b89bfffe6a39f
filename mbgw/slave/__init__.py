"""Lines in slave mode (mbgw the bus master) and the Modbus TCP face: `mbgw slave`, and the
target lines of any daemon.

May import routing, line, table, scenarios, upstream, net, ops, protocol, config,
firewall, web, besides errors and audit.
See docs/architecture.md#details-the-modbus-tcp-face-and-lines-in-slave-mode.
"""
