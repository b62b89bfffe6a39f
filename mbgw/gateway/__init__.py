"""The daemon of each mode, composed: its lines (targets and serial faces), the Modbus TCP face,
the table and the remote servers, wired by the routes, around one skeleton.  The one
package below cli that may import every mode's package.

May import routing, slave, master, transparent, scenarios, upstream, line, monitor,
net, table, ops, protocol, config, firewall, web, northbound, besides errors and audit.
See docs/architecture.md#threads.
"""
