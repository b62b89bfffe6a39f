"""`mbgw master`: a Modbus master on the serial line reaches Modbus TCP servers.

The path of one request, in three files: `line_thread` reads a request off the serial line
(csrc/request.c), routes its address through the slaveid table (mbgw.config.slaveid) and,
unless that address is down and no probe is due (answered at once), hands it to `upstream`,
the pool of TCP connections to the servers, which sends it with a transaction id of its own
and checks the reply; `line_thread` writes the reply (or 0x0B/0x0A, or nothing) back on the
line with the master's address.  `daemon` starts and stops it;
`status` and `trace` report it through mbgw.ops."""
