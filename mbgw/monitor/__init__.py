"""Listen-only lines (`[[line]]` with `mode = "monitor"`): the bus's own master and slaves
heard, never answered or written to; the answered values stored in the exchange table under
the `[[monitor]]` maps.  A monitor line is neither face nor target.

May import line, table, ops, protocol, config, besides errors and audit.
See docs/architecture.md#details-monitor-lines.
"""
