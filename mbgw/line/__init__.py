"""The serial line for every mode: opening it, framing, the C calls, and the skeleton of every
line thread (`supervisor.LineThread`: one thread per line).

May import protocol and the C core (mbgw._ffi), besides errors and audit.
See docs/architecture.md#the-model.
"""
