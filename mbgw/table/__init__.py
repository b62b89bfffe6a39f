"""The exchange table (issue 14): 65,536 registers of local data that Modbus TCP clients, a
serial master and the operator read and write, and the Modbus server that answers from it.

`memory` wraps the C core's table (csrc/table.c: zones, bit mapping, every check and
exception, one lock per request, counters): `Table`, and `Table.responder()` for each thread
that answers requests; `identity` fills the configuration zone from the settings; `persist`
keeps the outputs and the free zone in a file across restarts.  On a request's path: slave
mode's server (a unit id of the table) and master mode's line thread (a request for the table
address) hand the request to a responder, whose one C call answers it under the table's lock
and writes the reply into the responder's own buffer; nothing waits for the serial line.
May import protocol, config, errors and the C core (mbgw._ffi)."""
