"""Modbus itself, with no I/O and no threads: the MBAP header of Modbus TCP (`mbap`) and what a
PDU says about itself (`pdu`: broadcast, exception replies).  Every other part may use it."""
