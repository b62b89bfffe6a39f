"""`mbgw master`, and every line in master mode: a Modbus master on a serial line reaches
Modbus TCP servers, the exchange table and other lines (its *serial face*).

The path of one request: `serial_face` reads a request off the serial line
(csrc/request.c) and looks up its address's hop (`face_routes`: the face's routes, else the
slaveid table, mbgw.config.slaveid).  A server's request, unless that address is down and no
probe is due (answered at once), goes to `upstream`, the pool of TCP connections to the
servers, which sends it with a transaction id of its own and checks the reply; a line's goes
to that line's thread (mbgw.routing); the table's is answered by `table_slave`.
`serial_face` writes the reply (or 0x0B/0x0A, or nothing) back on the line with the master's
address.  `daemon` starts and stops the faces; `status` and `trace` report them through
mbgw.ops."""
