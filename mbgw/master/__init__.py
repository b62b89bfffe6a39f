"""Lines in master mode (serial faces): a Modbus master on a serial line reaches Modbus TCP
servers, the exchange table and other lines; `mbgw master`.

May import routing, line, table, scenarios, upstream, net, ops, protocol, config,
firewall, web, besides errors and audit.
See docs/architecture.md#details-serial-faces-lines-in-master-mode.
"""
