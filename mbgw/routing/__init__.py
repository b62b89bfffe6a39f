"""Faces, routes and targets at run time (`queue`): a face builds an `Exchange` and submits it
to the target's `Inbox`; the target's thread takes it in turn (`Scheduler`, a turn per
source) and calls its `done`; a face that waits on its own thread for the answer does so
with an `AnswerWait`.  slave and master (which implement faces and targets) import it, never
the other way round.

May import ops, protocol, config, besides errors and audit.
See docs/architecture.md#the-model.
"""
