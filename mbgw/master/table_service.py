"""Master mode's exchange table beside the line: the table itself (the line thread's
serial slave answers from it, mbgw.master.table_slave), its Modbus TCP server on
`table-port` (mbgw.table.server, a thread of its own; with TLS on `tls-port` too) while
the table is on, its file
(`table-persist`, mbgw.table.persist: loaded at start, saved by tick() and at stop), and the
settings a reload changes.  Asyncio thread, but for the server's own thread."""
import logging
import time

from mbgw.config.model import MasterConfig, TableConfig, TlsConfig
from mbgw.errors import ConfigError, ListenError
from mbgw.firewall.guard import Firewall
from mbgw.net.acl import AccessList
from mbgw.net.tls import server_context
from mbgw.ops.reload import ReloadReport
from mbgw.table import identity
from mbgw.table.control import table_commands, while_on
from mbgw.table.memory import Table
from mbgw.table.persist import Persistence
from mbgw.table.report import table_status
from mbgw.table.server import TableServer

log = logging.getLogger("mbgw.table")


class TableService:
    def __init__(self, settings: MasterConfig) -> None:
        self.cfg = cfg = settings.table
        self.table = Table()
        self.table.set_functions(cfg.functions, cfg.serial_functions)
        identity.fill(self.table, settings, "master")
        self.server: TableServer | None = None
        # on the TCP server's requests
        self.firewall = Firewall(settings.firewall, settings.tls.roles_required)
        self.tls = settings.tls
        self.request_timeout_s = settings.request_timeout_ms / 1000
        self.authip, self.bind = settings.authip, settings.bind
        self._commands = table_commands(self.table)
        self.persistence: Persistence | None = None
        if cfg.enabled and cfg.persist:
            self.persistence = Persistence(self.table, cfg.persist, cfg.persist_interval_s)

    def start(self) -> None:
        """Load the table's file, serve the table on table-port when it is on.  Raises
        ConfigError (the file cannot be read), ListenError."""
        if self.persistence is not None:
            self.persistence.load()
        if self.cfg.enabled:
            self._start_server(self.cfg.port)

    def tick(self) -> None:
        """Periodic (any thread but the line's): the file saved if the table changed and its
        interval has passed."""
        if self.persistence is not None:
            self.persistence.maybe_save(time.monotonic())

    def _start_server(self, port: int) -> None:
        """Raises ListenError, ConfigError (the TLS files)."""
        tls = self.tls
        context = server_context(tls) if tls.enabled else None
        self.server = TableServer(self.table, port, self.bind, firewall=self.firewall,
                                  allows=AccessList(self.authip).allows, tls=context,
                                  tls_port=tls.port,
                                  max_connections=self.cfg.max_connections)
        self.server.request_timeout_s = self.request_timeout_s
        self.server.start()
        log.info("exchange table served on %s (at most %d clients)",
                 ", ".join(self.server.addresses), self.cfg.max_connections)

    def commands(self) -> dict:
        """The operator's table-read and table-write, while the table is on."""
        return while_on(self._commands, lambda: self.cfg.enabled)

    def reconfigure(self, settings: MasterConfig, report: ReloadReport) -> None:
        """New settings (SIGHUP): functions and the configuration zone at once, the server
        started, stopped or moved.  A port that cannot be listened on, TLS files that do not
        load, go to the report, and what runs stays."""
        new = settings.table
        old, self.cfg = self.cfg, new
        identity.fill(self.table, settings, "master")
        self._repersist(old, new, report)
        if (new.functions, new.serial_functions) != (old.functions, old.serial_functions):
            self.table.set_functions(new.functions, new.serial_functions)
        firewall = self.firewall.renewed(settings.firewall,
                                          settings.tls.roles_required)
        if firewall is not self.firewall:
            self.firewall = firewall
            if self.server is not None:
                self.server.set_firewall(firewall)
        old_tls = self.tls
        self.tls = settings.tls
        self.request_timeout_s = settings.request_timeout_ms / 1000
        if self.server is not None:
            self.server.request_timeout_s = self.request_timeout_s
            self.server.max_connections = new.max_connections
        self._readdress(settings, report)
        try:
            if not new.enabled:
                self._stop_server()
            elif self.server is None:
                self._start_server(new.port)
            elif new.port != self.server.port:
                self.server.move(new.port)
        except ListenError as err:
            report.refuse("table", f"{err.strerror}; the table's TCP server is left as it was")
        except ConfigError as err:
            report.refuse("tls", f"{err}; the table's TCP server is not started")
            self.tls = old_tls
        if self.server is not None and settings.tls != old_tls:
            self._retls(settings.tls, old_tls, report)

    def _readdress(self, settings: MasterConfig, report: ReloadReport) -> None:
        """authip and bind: the clients no longer allowed closed, the listeners moved (the
        old address stays when the new one cannot be listened on)."""
        server = self.server
        if settings.authip != self.authip:
            self.authip = settings.authip
            if server is not None:
                server.set_access(AccessList(self.authip).allows)
        if settings.bind != self.bind:
            if server is not None:
                try:
                    server.rebind(settings.bind)
                except ListenError as err:
                    report.refuse("bind", f"{err.strerror}; the table is still served on "
                                          f"{', '.join(server.addresses) or 'no port'}")
                    return
            self.bind = settings.bind

    def _retls(self, new: TlsConfig, old: TlsConfig, report: ReloadReport) -> None:
        """New TLS settings or renewed files: for new connections, those open keep theirs.
        Ones that cannot be loaded leave TLS as it was."""
        assert self.server is not None
        try:
            context = server_context(new) if new.enabled else None
            self.server.set_tls(context, new.port)
        except (ConfigError, ListenError) as err:
            report.refuse("tls", f"{err}; the running TLS settings stay")
            self.tls = old

    def _repersist(self, old: TableConfig, new: TableConfig, report: ReloadReport) -> None:
        keeping = self.persistence is not None and new.enabled and new.persist == old.persist
        if keeping:
            assert self.persistence is not None
            self.persistence.interval_s = new.persist_interval_s
        elif (old.enabled and old.persist) != (new.enabled and new.persist):
            report.refuse("table.persist", "takes effect at restart (the table is still kept "
                          f"in {self.persistence.path if self.persistence else 'no file'})")

    def _stop_server(self) -> None:
        server, self.server = self.server, None
        if server is not None:
            server.stop()
            server.join()
            log.info("exchange table no longer served on port %d", server.port)

    def stop(self) -> None:
        """After the line thread has ended: nothing writes the table any more."""
        self._stop_server()
        if self.persistence is not None:
            self.persistence.save()

    def firewall_report(self) -> dict | None:
        """The firewall's status, when the file has rules (or denies by default)."""
        if not self.firewall.configured:
            return None
        server = self.server
        return self.firewall.report(server.firewall_clients() if server is not None else ())

    def clients(self) -> list[dict]:
        """The table server's clients (none while it is off)."""
        server = self.server
        return server.clients() if server is not None else []

    def close_client(self, client_id: int, who: str) -> bool:
        server = self.server
        return server is not None and server.close_client(client_id, who)

    def reset_counts(self) -> None:
        self.firewall.reset_counts()
        self.table.reset_counts()
        if self.server is not None:
            self.server.reset_counts()

    def figures(self, serial: dict) -> dict | None:
        """The table's part of the status (mbgw.table.report), with the TCP server's
        figures; None while the table is off."""
        cfg = self.cfg
        if not cfg.enabled:
            return None
        persistence = self.persistence
        persist = None if persistence is None else persistence.report()
        server = self.server
        return table_status(self.table, cfg, serial, persist,
                            server.figures() if server is not None else None)
