"""A listen-only line (`mode = "monitor"`): the bus's own master and slaves heard, never
answered; the answered values stored in the exchange table under `[[monitor]]` maps."""
