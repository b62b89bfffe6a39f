"""Modbus itself, with no I/O and no threads: the MBAP header of Modbus TCP (`mbap`) and what a
PDU says about itself (`pdu`).

May import nothing, besides errors and audit.
See docs/architecture.md#the-packages.
"""
