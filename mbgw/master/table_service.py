"""Master mode's exchange table (issue 14) beside the line: the table itself (the line thread's
serial slave answers from it, mbgw.master.line_thread), its Modbus TCP server on
`table-port` (mbgw.table.server, a thread of its own) while the table is on, and the settings
a reload changes.  Asyncio thread, but for the server's own thread."""
import logging

from mbgw.config.model import MasterConfig
from mbgw.table import identity
from mbgw.table.control import table_commands
from mbgw.table.memory import Table
from mbgw.table.server import MAX_CONNECTIONS, TableListenError, TableServer

log = logging.getLogger("mbgw.table")


class TableService:
    def __init__(self, settings: MasterConfig) -> None:
        self.cfg = cfg = settings.table
        self.table = Table(cfg.functions)
        identity.fill(self.table, settings, "master")
        self.server: TableServer | None = None
        self._commands = table_commands(self.table)

    def start(self) -> None:
        """Serve the table on table-port when it is on; raises TableListenError."""
        if self.cfg.enabled:
            self._start_server(self.cfg.port)

    def _start_server(self, port: int) -> None:
        self.server = TableServer(self.table, port)
        self.server.start()
        log.info("exchange table served on %s (at most %d clients)",
                 ", ".join(self.server.addresses), MAX_CONNECTIONS)

    def commands(self) -> dict:
        """The operator's table-read and table-write, while the table is on."""
        def when_on(command):
            def serve(request: dict) -> dict:
                if not self.cfg.enabled:
                    return {"error": "the exchange table is off (--table, [table] enabled)"}
                return command(request)
            return serve
        return {name: when_on(command) for name, command in self._commands.items()}

    def reconfigure(self, settings: MasterConfig) -> None:
        """New settings (SIGHUP): functions and the configuration zone at once, the server
        started, stopped or moved.  A port that cannot be listened on is logged, and the old
        one kept."""
        new = settings.table
        old, self.cfg = self.cfg, new
        identity.fill(self.table, settings, "master")
        if new.functions != old.functions:
            self.table.set_functions(new.functions)
        try:
            if not new.enabled:
                self._stop_server()
            elif self.server is None:
                self._start_server(new.port)
            elif new.port != self.server.port:
                self.server.move(new.port)
        except TableListenError as err:
            log.error("%s; the table's TCP server is left as it was", err.strerror)

    def _stop_server(self) -> None:
        server, self.server = self.server, None
        if server is not None:
            server.stop()
            server.join()
            log.info("exchange table no longer served on port %d", server.port)

    def stop(self) -> None:
        self._stop_server()

    def reset_counts(self) -> None:
        self.table.reset_counts()
        if self.server is not None:
            self.server.reset_counts()

    def figures(self, serial: dict) -> dict:
        """The table's part of the status: settings, the serial slave's figures (serial), the
        TCP server's, the requests by function and the exceptions sent."""
        cfg = self.cfg
        server = self.server
        return {"enabled": cfg.enabled, "address": cfg.address, "port": cfg.port,
                "functions": list(cfg.functions), "serial": serial,
                "tcp": server.figures() if server is not None else None,
                "tcp_connections": server.connections() if server is not None else [],
                **self.table.counts()}
