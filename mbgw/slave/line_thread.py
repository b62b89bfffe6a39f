"""The serial line's one owner, and the reader and writer of slave mode's TCP connections:
a thread that reads the clients' requests, takes jobs from the scheduler, runs them on the
line and delivers each outcome.  It also keeps the port alive: a device that fails is closed,
reopened when it is back (mbgw.line.supervisor), and reported once per change of state.

With the exchange table on, the thread holds the gate (a lock) at all times except around
its blocking serial calls, and the table reader (mbgw.slave.table_reader) serves the clients
meanwhile; every reply is then written by Python under the gate (no forward from C, no
shortcut), so no two threads ever write one socket.

An address that is down is probed by this thread itself, between two jobs, at its probe
interval, with the request kept for it (DeviceStats.probe_adu) and the device's own learnt
timeout, whether or not a client asks; the idle wait ends when the first probe is due.

What the thread holds, each with its own job: the read cache (mbgw.slave.line_cache), the
requests of other faces, Exchanges through an Inbox (use_inbox, mbgw.slave.line_exchanges; a
target line, mbgw.slave.targets, has no client of its own and takes only those), and the
serial scenarios, which take the scenario queue's turn in the scheduler's ring (use_scenarios,
mbgw.slave.line_scenarios)."""
import contextlib
import errno
import logging
import math
import threading
import time

from mbgw.config.model import SlaveConfig
from mbgw.errors import LineTimeout, SerialError
from mbgw.line.native import HEADER, HEADER_LEN, NO_FORWARD, Forward, Reception
from mbgw.line.serial_line import SerialLine
from mbgw.line.supervisor import TURN_MARGIN_S, LineThread, longest_frame_s
from mbgw.ops.counters import Counters
from mbgw.ops.device_stats import DeviceHealth
from mbgw.ops.exception_reply import gateway_exception
from mbgw.ops.trace import Outcome
from mbgw.protocol import pdu
from mbgw.routing.cache import WRITTEN
from mbgw.routing.queue import SCENARIO_TURN, Inbox, Job, Scheduler, SurveyRead
from mbgw.scenarios.engine import Scenarios
from mbgw.slave.connections import Client, Connections
from mbgw.slave.device_timing import DeviceTiming
from mbgw.slave.framing import framing_for
from mbgw.slave.line_cache import LineCache
from mbgw.slave.line_exchanges import LineExchanges
from mbgw.slave.line_scenarios import LineScenarios, serial_scenarios
from mbgw.slave.table_reader import Gate, TableReader
from mbgw.slave.transaction import SerialMaster

log = logging.getLogger("mbgw.line")
wire = logging.getLogger("mbgw.wire")

# Serial settings that need the port opened again; the others apply to the next transaction.
REOPEN_SETTINGS = ("device", "baudrate", "format", "interface", "rtsdelays", "dtr", "rts",
                   "cts", "xonxoff")


class SlaveLineThread(LineThread[SlaveConfig]):
    def __init__(self, cfg: SlaveConfig, line: SerialLine | None, scheduler: Scheduler,
                 server, counters: Counters, devices: DeviceHealth) -> None:
        super().__init__(cfg, line)
        self._scheduler = scheduler
        self._server = server          # the TcpServer
        self._connections: Connections = server.connections
        self._counters = counters
        self.devices = devices
        self._down = devices.rule.down     # the addresses that are down, by address
        self._finished = server.finished   # finished(job, reply_pdu_or_None[, forwarded])
        # deliver(job, reply_pdu_or_None[, bytes of it forwarded]): the client's, until
        # exchanges come too (use_inbox), so that a daemon of one line pays no dispatch per
        # request
        self._deliver = self._finished
        self._exchanges: LineExchanges | None = None   # from other faces (use_inbox)
        self._taken: Job | None = None     # put on the line by the shortcut, books to keep
        self._probed = False               # the last turn sent a probe
        self._shortcut = False
        self._gate = Gate()                  # see the module's docstring
        self._reader: TableReader | None = None     # while the table is on
        self._timing = self._retime()
        self._master: SerialMaster | None = self._master_on(line) if line else None
        self._scenarios: LineScenarios | None = None   # the serial scenarios (use_scenarios)
        self._timed_out: dict[int, Job] = {}   # by address: the job whose late reply may come
        self.cache = LineCache(server.cache, cfg.cache)   # reads that share one transaction
        # set before reconfigure(): the routes' rules to this line changed (slave.targets)
        self.empty_cache = False
        self.configured = threading.Event()    # set when new settings are in force
        self.watch_raw(server.trace)
        if line is None:
            self._line_state(down=True)

    def name_line(self, name: str) -> None:
        """Also the line whose [[device]] tables it takes (before start())."""
        super().name_line(name)
        self._timing = self._retime()
        if self._master is not None and self._line is not None:
            self._master = self._master_on(self._line, self._master)

    def _retime(self) -> DeviceTiming:
        """The timing by address of the settings in force, its demotions told to the
        devices."""
        cfg = self._cfg
        timing = DeviceTiming.of_line(cfg, self.line_name)
        self.devices.set_rule(cfg.demotion, timing.demotions(cfg.demotion),
                              cfg.serial.stout_ms)
        return timing

    def _master_on(self, line: SerialLine, previous: SerialMaster | None = None) -> SerialMaster:
        cfg = self._cfg
        master = SerialMaster(framing_for(line), cfg.serial, self._counters, self.devices,
                              cfg.retries, cfg.turnaround_ms, cfg.late_window, self._timing)
        master.on_late = self._late
        if previous is not None:
            master.keep_line_state(previous)
        # The shortcut takes plain RTU requests, which libmodbus sends and frames.
        # Not with the table on: C would write a reply to a client the table reader may be
        # answering at the same time.
        # Nor when the TCP face routes units elsewhere: C would put them on this line.
        self._shortcut = cfg.shortcut and cfg.serial.protocol == "rtu" and \
            line.libmodbus_sends and not cfg.serial.nocheck and self._server.shortcut_allowed \
            and cfg.cache is None      # C would put a read the cache answers on the line
        if self._shortcut:
            line.port.shortcut_rules(pdu.LIBMODBUS_FRAMED, line.char_ns,
                                     cfg.serial.stout_ms * 1_000_000, cfg.slaveid, self._down,
                                     master.late_until, self._timing.flags)
        return master

    # --- the line thread's hooks (mbgw.line.supervisor.LineThread) ---

    @property
    def turn_limit_s(self) -> float:
        """A transaction with its retries (each a quiet line, the longest request, stout, the
        longest reply's end; a scenario's retries may be more than the line's) and the pause
        after a broadcast."""
        cfg = self._cfg
        s = cfg.serial
        timing = self._timing
        quiet_ms = max(s.t35_us / 1000, s.silence_ms, timing.longest_pause_ms) + \
            sum(s.rtsdelays) + s.interframe_ms
        attempt_s = (quiet_ms + timing.longest_stout_ms) / 1000 + 2 * longest_frame_s(s)
        retries = max((sc.retries for sc in serial_scenarios(cfg)), default=cfg.retries)
        return (max(retries, timing.most_retries) + 1) * attempt_s + \
            cfg.turnaround_ms / 1000 + TURN_MARGIN_S

    def _wake(self) -> None:
        self._scheduler.wake()

    def run(self) -> None:
        self._gate.take_for_line()
        try:
            self._start_reader()
            super().run()
        finally:
            self._gate.release()

    def _open_line(self) -> SerialLine:
        return SerialLine(self._cfg.serial, self._counters)

    def _attach(self, line: SerialLine) -> None:
        self._master = self._master_on(line)
        self._line_state(down=False)

    def _detach(self) -> None:
        self._master = None
        self._line_state(down=True)

    def _line_state(self, down: bool) -> None:
        """FC 7 of the exchange table tells whether the line is down."""
        table = self._server.table
        if table is not None:
            table.set_flags(line_down=down)

    def _reopens(self, old, new) -> bool:
        return any(getattr(new, name) != getattr(old, name) for name in REOPEN_SETTINGS)

    def _configure(self, old: SlaveConfig, reopen: bool) -> None:
        self._server.route_face(self._cfg)
        self._timing = self._retime()      # the line's stout, retries and devices'
        if (self._reader is not None) != self._server.reads_meanwhile:
            self._stop_reader()
            self._start_reader()
        if self._scenarios is not None:
            self._scenarios.configure(old, self._cfg)
        if not reopen and self._master is not None and self._line is not None:
            self._master = self._master_on(self._line, self._master)
        self.cache.configure(old, self._cfg, self.empty_cache)
        self.empty_cache = False
        self.configured.set()

    def _turn(self) -> None:
        scenarios = self._scenarios
        if scenarios is not None and (scenarios.active or scenarios.woken):
            scenarios.due()
        master = self._master
        assert master is not None
        if 1 in self._down and self._probe(master):
            self._connections.wait(0)      # what the clients sent meanwhile
            return
        job = self._scheduler.take(master.held if master.late_open else None)
        if job is SCENARIO_TURN:
            assert scenarios is not None       # its turn comes only when one is due
            scenarios.run(master)
            self._connections.wait(0)      # what the clients sent meanwhile
        elif job is None:
            self._idle()
            job, self._taken = self._taken, None
            if job is not None:
                self._serve_taken(job)
        elif not self._refused_as_down(job):
            self._serve(job)
            self._connections.wait(0)      # what the clients sent meanwhile

    # --- probes of the addresses that are down (mbgw.ops.device_stats) ---

    def _probe(self, master: SerialMaster) -> bool:
        """Send one probe that is due, unless the last turn sent one and jobs wait: a
        probe goes between two jobs, so a waiting client is never behind more than one
        probe's timeout.  Whether one went."""
        if self._probed and self._scheduler.depth:
            self._probed = False
            return False
        now = time.monotonic()
        for device in self.devices.probing():
            if master.late_open and master.held(device.address or 0):
                continue
            adu = device.probe_due(now)
            if adu is not None:
                self._probed = True
                self._send_probe(master, adu, int(device.probe_timeout_ms() * 1_000_000))
                return True
        self._probed = False
        return False

    def _send_probe(self, master: SerialMaster, adu: bytes, timeout_ns: int) -> None:
        """adu on the line, waiting timeout_ns for its reply, without retries; the reply
        (booked: the device is back) goes nowhere."""
        try:
            self._on_line(master, adu, 0, timeout_ns)
        except LineTimeout:
            pass
        except SerialError as err:
            self._lost(err)
        except Exception:   # a bug must cost one probe, never the line
            log.exception("internal error probing with %s", adu.hex(" "))

    def _next_probe_ms(self) -> int:
        """Until the first probe due (rounded up; -1: none)."""
        if 1 not in self._down:
            return -1
        due = [d.probe_at for d in self.devices.probing()]
        if not due:
            return -1
        return max(0, math.ceil((min(due) - time.monotonic()) * 1000))

    def _while_down(self, timeout_s: float) -> None:
        self._reject_waiting()             # requests are refused at once meanwhile
        if self._scenarios is not None:
            self._scenarios.while_down()
        self._connections.wait(int(timeout_s * 1000))

    def _finish(self) -> None:
        self._stop_reader()
        self._connections.close_all()
        self.close_line()
        if self._exchanges is not None:    # what waits for this line is refused (removed)
            self._reject_waiting()
            self._inbox_ready()

    # --- the table reader (the gate is held) ---

    def _start_reader(self) -> None:
        if self._server.reads_meanwhile:
            table = self._server.table
            self._reader = TableReader(self._gate, self._connections, self._scheduler.wake_fd,
                                       self._server.read_meanwhile,
                                       table.responder() if table is not None else None)
            self._reader.start()

    def _stop_reader(self) -> None:
        reader, self._reader = self._reader, None
        if reader is not None:
            reader.stop()
            with self._gate.line_away:
                reader.join()
            self._server.take_kept()

    def _exchange_job(self, master: SerialMaster, job: Job, forward) -> Reception | None:
        """master.exchange, without the gate while the table reader runs; the gate is back
        when it returns.  The requests the reader kept for the line meanwhile are routed
        once the reply has gone on (_serve), or at once when there is none (it raised)."""
        if self._reader is None:
            return master.exchange(job.adu, forward)
        try:
            with self._gate.line_away:
                return master.exchange(job.adu, forward)
        except BaseException:
            self._server.take_kept()
            raise

    # --- serving ---

    def _serve(self, job: Job) -> None:
        """job on the line; its outcome to its client (or face) at once, the books after."""
        if not self._answered_off_the_line(job):
            self._transact(job)

    def _forward(self, job: Job) -> Forward:
        """Where the reply may go straight from the C receive: to a client whose earlier
        replies have all gone out.  With no other request waiting for the line, that client
        (often woken onto this CPU) then runs before our bookkeeping.  Not a write's on a
        line with a cache: what it overlaps is dropped first (LineCache.after)."""
        client = job.client
        if self._reader is None and client is not None and \
                not (self.cache.caching and job.adu[1] in WRITTEN):
            return client.forward_target(job.tid, job.unit, not self._scheduler.depth)
        return NO_FORWARD

    def _transact(self, job: Job) -> None:
        """_serve's transaction: job on the line, its outcome delivered, then its books."""
        rule = job.cache
        cache = self.cache
        got = None
        forwarded = -1
        try:
            forward = self._forward(job)
            master = self._master
            assert master is not None          # jobs are served only while the line is up
            got = self._exchange_job(master, job, forward)
            if got is None:
                job.outcome = Outcome.BROADCAST
                reply = None
            else:
                frame = got.frame
                assert frame is not None       # exchange() returns replies only
                reply = frame[1:]
                forwarded = got.forwarded
                job.outcome = Outcome.DEVICE_EXCEPTION if reply[0] & pdu.EXCEPTION_FLAG \
                    else Outcome.REPLY
        except LineTimeout:
            job.outcome = Outcome.TIMEOUT
            reply = self._failure(job, pdu.GATEWAY_TARGET_FAILED)
        except SerialError as err:
            self._lost(err)
            job.outcome = Outcome.LINE_DOWN
            reply = self._failure(job, pdu.GATEWAY_PATH_UNAVAILABLE)
        except Exception:   # a bug must cost one transaction, never the line
            log.exception("internal error serving %s", job.adu.hex(" "))
            job.outcome = Outcome.ERROR
            reply = self._failure(job, pdu.GATEWAY_PATH_UNAVAILABLE)
        if rule is not None or cache.caching:
            reply = cache.after(job, rule, got, reply)
        try:
            self._deliver(job, reply, forwarded)
        except Exception:
            log.exception("internal error delivering the outcome of %s", job.adu.hex(" "))
        master = self._master
        if got is not None and master is not None:
            try:
                master.book(got)
            except Exception:   # a bug must cost one transaction's books, never the line
                log.exception("internal error booking %s", job.adu.hex(" "))
        if self._reader is not None:
            self._server.take_kept()
        if master is not None and master.late_until[job.adu[0]]:
            self._timed_out[job.adu[0]] = job       # a try timed out: its reply may come

    def _answered_off_the_line(self, job: Job) -> bool:
        """A job that needs no transaction of its own: one its face withdrew, an operator's
        survey read (it takes the line its own way), a read the cache answers."""
        if job.client is None:
            if LineExchanges.withdrawn(job):
                return True
            if type(job.exchange) is SurveyRead:
                self._survey(job, job.exchange)
                return True
        rule = job.cache
        # a probe of a unit that is down goes on the line: it is what brings the unit back
        if rule is None or job.probe:
            return False
        reply = self.cache.at_turn(job, rule)
        if reply is None:
            return False
        self._deliver_safely(job, reply)
        return True

    def _serve_taken(self, job: Job) -> None:
        """job, which the shortcut has put on the line already (_take): what C received is
        handed to the master, then served as any job (a write that failed: the line is
        lost)."""
        master = self._master
        try:
            assert master is not None
            master.book_taken(master.framing.port.exchanged())
        except SerialError as err:
            self._lost(err)
            job.outcome = Outcome.LINE_DOWN
            self._deliver_safely(job, self._failure(job, pdu.GATEWAY_PATH_UNAVAILABLE))
            return
        except Exception:   # a bug must cost one transaction, never the line
            log.exception("internal error serving %s", job.adu.hex(" "))
            job.outcome = Outcome.ERROR
            self._deliver_safely(job, self._failure(job, pdu.GATEWAY_PATH_UNAVAILABLE))
            return
        self._serve(job)

    def _deliver_safely(self, job: Job, reply: bytes | None, forwarded: int = -1) -> None:
        try:
            self._deliver(job, reply, forwarded)
        except Exception:
            log.exception("internal error delivering the outcome of %s", job.adu.hex(" "))

    def _refused_as_down(self, job: Job) -> bool:
        """A job queued before its address went down is refused now, unless it is the probe
        (admitted as one when it came, or now if one is due)."""
        address = job.adu[0]
        if not self._down[address] or job.probe:
            return False
        device = self.devices.get(address)
        if device.admit(time.monotonic()):
            return False
        stale = self.cache.stale_for_down(job)
        if stale is not None:
            self._deliver(job, stale)
            return True
        self._counters.demoted_rejects += 1
        job.outcome = Outcome.DEVICE_DOWN
        self._deliver(job, self._failure(job, pdu.GATEWAY_TARGET_FAILED))
        return True

    def _late(self, frame: bytes) -> None:
        """A late reply (address + PDU) was dropped: traced with the request it answered."""
        job = self._timed_out.get(frame[0])
        if job is not None and job.client is not None:
            self._server.traced_late(job, frame[1:])

    def _failure(self, job: Job, code: int) -> bytes | None:
        if job.adu[0] == pdu.BROADCAST:
            return None
        return gateway_exception(self._cfg.exception, job.adu[1], code, self._counters,
                                 self.devices.get(job.adu[0]))

    def _idle(self) -> None:
        """Wait for a request, new settings or stopping; count input nobody asked for."""
        assert self._master is not None
        port = self._master.framing.port
        take = self._take if self._shortcut else None
        try:
            if self._connections.wait(self._idle_timeout_ms(), port.fd, take):
                self._master.hear()     # a frame without a request: a late reply, or noise
        except SerialError as err:
            self._lost(err)

    def _idle_timeout_ms(self) -> int:
        """The idle wait ends in time for the next scenario (or stale-after check), and when
        requests wait for a late window, when the first window ends (rounded up).  poll()
        counts whole ms: it stops short and the last fraction is slept (well under a ms of
        the clients' time)."""
        idle_ms = self.idle_ms
        probe_ms = self._next_probe_ms()
        if probe_ms >= 0:
            idle_ms = probe_ms if idle_ms < 0 else min(probe_ms, idle_ms)
        if self._scheduler.depth and self._master is not None and self._master.late_open:
            left_ns = self._master.next_window_end_ns() - time.monotonic_ns()
            window_ms = max(0, -(-left_ns // 1_000_000))
            idle_ms = window_ms if idle_ms < 0 else min(window_ms, idle_ms)
        scenarios = self._scenarios
        due = scenarios.due_s if scenarios is not None and scenarios.active else None
        if due is None:
            return idle_ms
        if due < 0.001:
            time.sleep(due)
            return 0
        due_ms = int(due * 1000)
        return due_ms if idle_ms < 0 else min(due_ms, idle_ms)

    def _take(self, client: Client) -> list | None:
        """The shortcut for a request that finds the line idle: C reads the client and, when
        what came is one request it can put on the line as it is, exchanges it at once and
        forwards the reply; the books are kept after (self._taken).  Anything else read is
        the client's to frame.  Returns what Client.receive would."""
        master = self._master
        assert master is not None
        port = master.framing.port
        client.admitted()              # from now on, never an idle connection to evict,
        client.requests += 1           # nor one that never sent a request, once answered
        take = port.take_request(client.fd, master.quiet_until_ns, client.flight)
        data = take.input
        if not take.taken:
            client.answered()
            client.requests -= 1
            if take.status == -errno.EAGAIN:
                return []
            return client.received(data, take.arrived_ns) if take.status > 0 else None
        tid, _, _, unit = HEADER.unpack_from(data)
        client.last_active = time.monotonic()
        try:
            self._taken = self._server.taken(client, tid, unit, data[HEADER_LEN:],
                                             take.arrived_ns)
        except Exception:   # a bug must cost one transaction, never the line
            log.exception("internal error on a request the shortcut took: %s", data.hex(" "))
        if self._taken is None:
            client.answered(take.forwarded)     # no job will: C may have, forwarding
        return []

    def _reject_waiting(self) -> None:
        """While the port is down, nothing waits: every queued request is refused at once."""
        while (job := self._scheduler.take()) is not None:
            if job is SCENARIO_TURN:       # none runs while the line is down
                continue
            self._counters.line_down_rejects += 1
            job.outcome = Outcome.LINE_DOWN
            self._deliver(job, self._failure(job, pdu.GATEWAY_PATH_UNAVAILABLE))

    # --- exchanges: requests from other faces (the Modbus TCP face, a serial face) ---

    def use_inbox(self, inbox: Inbox) -> None:
        """Take the exchanges submitted to inbox (called once, before start()): one more fd
        in the idle poll(), nothing per request until the first exchange comes."""
        self._exchanges = LineExchanges(inbox, self._scheduler, self._counters, self.devices,
                                        self.cache, self._finished, self._failure)
        self._connections.poll_also(inbox.wake_fd, self._inbox_ready)

    def _inbox_ready(self) -> None:
        """Line thread: what was submitted admitted, each as a job in its source's queue."""
        exchanges = self._exchanges
        assert exchanges is not None
        self._deliver = exchanges.deliver    # outcomes go to clients and faces from now on
        exchanges.admit_all(self._line is not None)

    def _survey(self, job: Job, survey: SurveyRead) -> None:
        """An operator's survey read on the line (LineExchanges.survey), outside the gate."""
        line, master, exchanges = self._line, self._master, self._exchanges
        assert line is not None and master is not None and exchanges is not None
        reply = None
        try:
            reply, outcome = exchanges.survey(line, master, survey, self._timing,
                                              self._gate_away())
        except SerialError as err:
            self._lost(err)
            outcome = Outcome.LINE_DOWN
        except Exception:   # a bug must cost one read, never the line
            log.exception("internal error on a survey read %s", job.adu.hex(" "))
            outcome = Outcome.ERROR
        survey.done(survey, reply, outcome)

    def _gate_away(self):
        """The gate left to the table reader around a blocking call, while it runs; the
        requests it kept for the line are routed after."""
        if self._reader is None:
            return contextlib.nullcontext()
        return self._reader_away()

    @contextlib.contextmanager
    def _reader_away(self):
        try:
            with self._gate.line_away:
                yield
        finally:
            self._server.take_kept()

    # --- the serial scenarios ---

    def use_scenarios(self, engine: Scenarios) -> None:
        """Run engine's scenarios on this line, and those of the settings to come (called
        once, before start())."""
        self._scenarios = scenarios = LineScenarios(
            engine, self._cfg, self._scheduler, self.devices, self.cache, self._server.trace,
            self._scenario_on_line)
        self._connections.poll_also(engine.wake_fd, scenarios.ready)

    def _scenario_on_line(self, master: SerialMaster, adu: bytes, retries: int
                          ) -> bytes | None:
        """_on_line for a scenario's run; a lost line is closed before SerialError goes on."""
        try:
            return self._on_line(master, adu, retries)
        except SerialError as err:
            self._lost(err)
            raise

    def _on_line(self, master: SerialMaster, adu: bytes, retries: int, stout_ns: int = 0
                 ) -> bytes | None:
        """master.transact for a scenario or a probe, without the gate (the table reader
        serves the clients meanwhile); the requests it kept for the line are routed after."""
        if self._reader is None:
            return master.transact(adu, retries, stout_ns)
        try:
            with self._gate.line_away:
                return master.transact(adu, retries, stout_ns)
        finally:
            self._server.take_kept()
