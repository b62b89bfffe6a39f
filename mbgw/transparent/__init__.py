"""`mbgw transparent`: raw frames of a device that speaks no Modbus, exchanged with Modbus TCP
clients through the exchange table (VPGate 3.8).

May import routing, line, table, scenarios, upstream, net, ops, protocol, config,
firewall, web, besides errors and audit.
See docs/architecture.md#details-transparent-mode.
"""
