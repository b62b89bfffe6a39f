"""The serial line for every mode: opening it, the C calls and the frame rules they hold
(`native`: RTU, ASCII, MBAP), and the skeleton of every line thread (`supervisor.LineThread`:
one thread per line).

May import the C core (mbgw._ffi), besides errors and audit.
See docs/architecture.md#the-model.
"""
