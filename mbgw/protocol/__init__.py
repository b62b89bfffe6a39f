"""Modbus itself, with no I/O and no threads: what a PDU says about itself (`pdu`).  The MBAP
header of Modbus TCP is the C core's rule: mbgw.line.native.

May import nothing, besides errors and audit.
See docs/architecture.md#the-packages.
"""
