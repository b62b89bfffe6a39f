"""Modbus TCP connections to remote servers, shared by master mode and the TCP scenarios.

`pool` (`UpstreamPool`): one connection per server, at most `limit` open (the least recently
used closed first), requests in MBAP with a transaction id of its own, one at a time, every
wait a poll() that the owner's eventfd also wakes, each reply checked to answer its request.
It runs on its owner's thread: master mode's line thread, the scenarios' TCP runner.
May import line, ops, protocol, config, errors."""
