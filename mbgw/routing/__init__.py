"""Faces, routes and targets at run time: a face builds an `Exchange` and submits it to the
target's `Inbox`; the target's thread answers it and calls its `done`.  slave and master
(which implement faces and targets) import it, never the other way round.

May import ops, protocol, config, besides errors and audit.
See docs/architecture.md#the-model.
"""
