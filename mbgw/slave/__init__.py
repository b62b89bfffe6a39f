"""`mbgw slave`: Modbus TCP clients reach the slaves on a serial line.

The path of one request, in five files: `server` admits the connection (authip, connection
limit) and routes each request to a serial address (refusing it at once when that address
is down and no probe is due); `connections` (with `client`) is the line thread's poll over
the clients, cutting their bytes into MBAP frames; `scheduler` queues requests, a FIFO per
client served round-robin; `line_thread` takes them one at a time and `transaction` puts
each on the line and awaits its reply, which goes back to its client from C at once or
from `server.finished`.  With the exchange table on (`--table`), `server` answers a table
request at once from the table, in the thread that read it: the line thread, or
`table_reader`, which reads the clients while the line thread is on the line;
`table_service` keeps the table's zone, file, commands and figures.  `daemon` starts and
stops it all; `status` reports it.
Trace, control socket, metrics and counters are mbgw.ops's."""
