"""The exchange table: 65,536 registers that Modbus TCP clients, serial masters and the
operator read and write, answered in C under the table's lock in the thread that read the
request; and its own Modbus TCP server (master and transparent mode).

May import net, line, protocol, config, firewall, ops and the C core (mbgw._ffi), besides
errors and audit.
See docs/architecture.md#tcp-face--table.
"""
