"""Slave mode's exchange table beside the line: the table itself (TcpServer answers
from it, in the line thread or the table reader), its configuration zone, its file
(persistence), the operator's commands and its figures; the settings a reload changes.
Asyncio thread."""
import asyncio
import logging
import time

from mbgw.config.model import SlaveConfig
from mbgw.ops.device_stats import DeviceHealth
from mbgw.ops.reload import ReloadReport
from mbgw.table import identity
from mbgw.table.control import table_commands, while_on
from mbgw.table.memory import Table
from mbgw.table.persist import Persistence
from mbgw.table.report import table_status

log = logging.getLogger("mbgw.table")

TICK_S = 1.0        # how often the file is looked at (it is written at most every interval)


class TableService:
    def __init__(self, settings: SlaveConfig, devices: DeviceHealth) -> None:
        """The table, built even while it is off (a reload may turn it on); FC 7 tells
        whether a device is down from the demotion's flags.  Raises ConfigError when the
        table's file is there but cannot be read."""
        self.settings = settings
        self.table = Table(settings.table.functions)
        self.table.watch_down(devices.rule.down)
        identity.fill(self.table, settings, "slave")
        self.persistence: Persistence | None = None
        self._persist(settings)
        self._commands = table_commands(self.table)

    @property
    def cfg(self):
        return self.settings.table

    def _persist(self, settings: SlaveConfig) -> None:
        """Keep the table in the file the settings name (loaded now), if any."""
        cfg = settings.table
        if not (settings.table_on and cfg.persist):
            self.persistence = None
            return
        self.persistence = Persistence(self.table, cfg.persist, cfg.persist_interval_s)
        self.persistence.load()

    def reconfigure(self, settings: SlaveConfig, report: ReloadReport) -> None:
        """New settings (SIGHUP): the configuration zone; a new file is loaded after the old
        one is written (one that cannot be read goes to the report: the table is not kept).
        The functions and the units are TcpServer's."""
        old, self.settings = self.settings, settings
        identity.fill(self.table, settings, "slave")
        if (settings.table_on, settings.table.persist, settings.table.persist_interval_s) \
                != (old.table_on, old.table.persist, old.table.persist_interval_s):
            self.save()
            try:
                self._persist(settings)
            except Exception as err:   # a reload never stops the gateway
                report.refuse("table", f"{err}; the table is not kept in a file")
                self.persistence = None

    async def keep(self) -> None:
        """Write the file when the table changed, at most every persist-interval (a task
        running until cancelled)."""
        while True:
            await asyncio.sleep(TICK_S)
            if self.persistence is not None:    # a write every interval at most: on the loop
                self.persistence.maybe_save(time.monotonic())

    def save(self) -> None:
        """At stop (and before another file is used)."""
        if self.persistence is not None:
            self.persistence.save()

    def commands(self) -> dict:
        """The operator's table-read and table-write, while the table is on."""
        return while_on(self._commands, lambda: self.settings.table_on)

    def figures(self) -> dict | None:
        """The status's "table" section (mbgw.table.report), None while the table is off."""
        if not self.settings.table_on:
            return None
        persist = None if self.persistence is None else self.persistence.report()
        return table_status(self.table, self.cfg, persist=persist)
