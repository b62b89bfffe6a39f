"""Faces, routes and targets at run time: a request routed from the face it came in on to the
target that answers it, on another thread.  A face builds an `Exchange` and submits it to the
target's `Inbox`; the target's thread answers it and calls its `done`.

May import protocol, config, ops and errors; slave and master (which implement faces and
targets) import it, never the other way round.  See docs/architecture.md, "Faces, routes and
targets".
"""
