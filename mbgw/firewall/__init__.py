"""The Modbus firewall ([[rule]] tables, mbgw.config.firewall) on the request path of every
Modbus TCP server: slave mode's (mbgw.slave.server, the line's requests and the table's) and
master mode's table server (mbgw.table.server).  `guard`: at connect time the first rule that
selects the client (role, CIDR, listener) is compiled into the client's Guard, so that a
request costs a few lookups (unit, function, address range from the PDU); counts per rule,
logs refusals per client at most once a minute."""
