"""The web console, on the daemon's asyncio loop (aiohttp): the same control commands and trace
hub as the control socket, never on a line thread's path.

May import net, ops, table, scenarios, config, protocol, besides errors and audit.
See docs/architecture.md#the-packages.
"""
