"""Scenarios (VPGate §3.5, §3.6.3): requests the gateway sends on its own to serial slaves and
Modbus TCP servers, cyclically or when table data changes, their data kept in the exchange
table.  A runner (a line thread in slave mode, the TCP runner) asks `engine.Scenarios` what
is due, sends it and hands back the reply.

May import table, upstream, line, net, ops, protocol, config, besides errors and audit.
See docs/architecture.md#details-tcp-scenarios.
"""
