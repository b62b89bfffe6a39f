"""The Modbus firewall ([[rule]] tables): a client's Guard, compiled when it connects, checked
per request by every Modbus TCP server.

May import net, protocol, config, besides errors and audit.
See docs/architecture.md#the-packages.
"""
