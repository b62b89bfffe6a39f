"""`mbgw transparent`: raw frames of a device that speaks no Modbus, exchanged with Modbus TCP
clients through the exchange table (VPGate 3.8).  `frames` (the rules, no I/O: where a frame
ends on the line, what is stored at rx-address, what the tx area sends), `line_thread`
(`TransparentLineThread`: the serial line, the tx area's watch and the raw port in one
poll()), `raw`
(`RawPort`: one TCP client's byte stream to the line), `counters`, `daemon`, `status`.

The path of one frame: bytes read from the tty are cut into frames by `frames.Receiver`
(an end character, the length byte, or eof-timeout of silence); a complete frame is checked
(crc), laid out by `frames.Rules.rx_area` and stored at rx-address in one `Table.write`, and
given to the raw client.  The other way, a TCP client's write to the tx area (mbgw.table.server)
sets the area's watch; the line thread takes the area (one copy under the table's lock),
`frames.Rules.tx_frame` cuts the frame out of it, and it is sent once `silence` has passed
since the line's last received byte."""
