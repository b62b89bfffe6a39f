"""The serial line's one owner, and the reader and writer of slave mode's TCP connections:
a thread that reads the clients' requests, takes jobs from the scheduler, runs them on the
line and delivers each outcome.  It also keeps the port alive: a device that fails is closed,
reopened when it is back (mbgw.line.supervisor), and reported once per change of state.

With the exchange table on, the thread holds the gate (a lock) at all times except around
its blocking serial calls, and the table reader (mbgw.slave.table_reader) serves the clients
meanwhile; every reply is then written by Python under the gate (no forward from C, no
shortcut), so no two threads ever write one socket.

The serial scenarios (an mbgw.scenarios engine, use_scenarios) run here too, under the same
rules: the scenario queue takes turns with the clients in the scheduler's ring, each run is a
SerialMaster transaction with the scenario's retries, a device that is down gets no run but
its probe (the same DeviceStats.admit as the clients' requests), and the idle wait ends when
the next scenario is due or the engine's eventfd says a change made one pending (or an
operator's `scenario test` waits: it runs in the scenario queue's turn too).

An address that is down is probed by this thread itself, between two jobs, at its probe
interval, with the request kept for it (DeviceStats.probe_adu) and the device's own learnt
timeout, whether or not a client asks; the idle wait ends when the first probe is due.

Requests from other faces come as Exchanges through an Inbox (use_inbox): a target line
(mbgw.slave.targets) has no client of its own and takes only those; each is admitted by the
same rules as a client's request and queued in its source's turn, and its outcome goes to
Exchange.done on this thread."""
import contextlib
import errno
import logging
import math
import threading
import time
from typing import Hashable

from mbgw.config.cache import CacheRule
from mbgw.config.model import SlaveConfig
from mbgw.errors import LineTimeout, SerialError
from mbgw.line.native import HEADER, HEADER_LEN, NO_FORWARD, Reception
from mbgw.line.serial_line import SerialLine
from mbgw.line.supervisor import TURN_MARGIN_S, LineThread, longest_frame_s
from mbgw.line.survey import ask_once
from mbgw.ops.counters import Counters
from mbgw.ops.device_stats import DeviceHealth
from mbgw.ops.exception_reply import gateway_exception
from mbgw.ops.trace import Outcome
from mbgw.protocol import pdu
from mbgw.routing.cache import WRITTEN, ReadCache, is_read, resolve
from mbgw.routing.queue import (
    SCENARIO_TURN,
    Exchange,
    Inbox,
    Job,
    Queue,
    Scheduler,
    SurveyRead,
)
from mbgw.scenarios.engine import Scenarios
from mbgw.scenarios.exchange import EXCEPTION_KINDS, FRAME_WITHOUT_REQUEST, TIMEOUT
from mbgw.scenarios.health import SerialHealth
from mbgw.scenarios.report import trace_event
from mbgw.slave.connections import Client, Connections
from mbgw.slave.device_timing import DeviceTiming
from mbgw.slave.table_reader import Gate, TableReader
from mbgw.slave.transaction import SerialMaster, framing_for

log = logging.getLogger("mbgw.line")
wire = logging.getLogger("mbgw.wire")

# A scenario's run while the serial device is lost: the engine's error kind for 0x0A.
PATH_UNAVAILABLE = EXCEPTION_KINDS[pdu.GATEWAY_PATH_UNAVAILABLE]
# Sources (TCP clients, serial faces) whose queue is kept while idle, before idle ones go.
MAX_SOURCES = 256
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
        self._inbox: Inbox | None = None   # exchanges from other faces (use_inbox)
        self._queues: dict[Hashable, Queue] = {}   # the exchanges' queues, by source
        self._taken: Job | None = None     # put on the line by the shortcut, books to keep
        self._probed = False               # the last turn sent a probe
        self._shortcut = False
        self._gate = Gate()                  # see the module's docstring
        self._reader: TableReader | None = None     # while the table is on
        self._timing = self._retime()
        self._master: SerialMaster | None = self._master_on(line) if line else None
        self._engine: Scenarios | None = None      # the serial scenarios' engine (use_scenarios)
        self._scenarios: Scenarios | None = None   # the engine while it has scenarios to run
        self._due_s: float | None = None   # until the next scenario is due (None: none is)
        self._engine_woken = False         # its eventfd was ready (a test, with no scenario)
        self._timed_out: dict[int, Job] = {}   # by address: the job whose late reply may come
        self._run_started = 0              # the scenario run traced last began (ns)
        self._trace = server.trace
        # reads that share one transaction (mbgw.routing.cache); _caching: some rule has
        # applied on this line, so its writes drop what they overlap
        self.cache: ReadCache = server.cache
        self._caching = cfg.cache is not None
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
        if self._engine is not None and self._cfg.scenarios != old.scenarios:
            scenarios = serial_scenarios(self._cfg)
            self._engine.reconfigure(scenarios)
            self._scenarios = self._engine if scenarios else None
            self._due_s = None
        if not reopen and self._master is not None and self._line is not None:
            self._master = self._master_on(self._line, self._master)
        if self.empty_cache or self._cfg.cache != old.cache or \
                route_caches(self._cfg) != route_caches(old):
            self.empty_cache = False
            self.cache.clear()
        self._caching = self._caching or self._cfg.cache is not None
        self.configured.set()

    def _turn(self) -> None:
        if self._scenarios is not None or self._engine_woken:
            self._scenarios_due()
        master = self._master
        assert master is not None
        if 1 in self._down and self._probe(master):
            self._connections.wait(0)      # what the clients sent meanwhile
            return
        job = self._scheduler.take(master.held if master.late_open else None)
        if job is SCENARIO_TURN:
            self._run_scenario()
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
        if self._engine is not None:
            self._scenarios_while_down(self._engine)
        self._connections.wait(int(timeout_s * 1000))

    def _finish(self) -> None:
        self._stop_reader()
        self._connections.close_all()
        self.close_line()
        if self._inbox is not None:    # what waits for this line is refused (it is removed)
            self._reject_waiting()
            self._exchanges()

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
        if self._answered_off_the_line(job):
            return
        client = job.client
        rule = job.cache
        got = None
        forwarded = -1
        try:
            # The reply may go straight to a client whose earlier replies have all gone out.
            # With no other request waiting for the line, that client (often woken onto this
            # CPU) then runs before our bookkeeping.  Not a write's on a line with a cache:
            # what it overlaps is dropped first (_cache_outcome).
            forward = client.forward_target(job.tid, job.unit, not self._scheduler.depth) \
                if self._reader is None and client is not None and \
                not (self._caching and job.adu[1] in WRITTEN) else NO_FORWARD
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
        if rule is not None or self._caching:
            reply = self._cache_outcome(job, rule, got, reply)
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
            if self._withdrawn(job):
                return True
            if type(job.exchange) is SurveyRead:
                self._survey(job, job.exchange)
                return True
        rule = job.cache
        # a probe of a unit that is down goes on the line: it is what brings the unit back
        return rule is not None and not job.probe and self._from_cache(job, rule)

    # --- the read cache (mbgw.routing.cache) ---

    def _from_cache(self, job: Job, rule: CacheRule) -> bool:
        """A read whose turn has come, answered from the cache if an identical read under
        way since it arrived, or fresh data, answers it; else it goes on the line (a miss)."""
        cache = self.cache
        reply = cache.answer(rule, job.adu, job.received_ns, time.monotonic_ns())
        if reply is None:
            cache.missed(job.adu)
            self._caching = True
            return False
        job.outcome = cache.outcome()
        self._deliver_safely(job, reply)
        return True

    def _cache_outcome(self, job: Job, rule: CacheRule | None, got: Reception | None,
                       reply: bytes | None) -> bytes | None:
        """After a transaction, before its reply goes out: a read's answer shared and kept,
        dated by the end of the slave's reply (C may have forwarded it already); stale data
        for a read that timed out; a write's overlap dropped.  The reply to send."""
        cache = self.cache
        adu = job.adu
        if rule is None:
            cache.written(adu)
            return reply
        now_ns = time.monotonic_ns()
        if got is not None:
            cache.answered(adu, reply, got.last_byte_ns or now_ns)
            return reply
        if job.outcome == Outcome.TIMEOUT:
            stale = cache.stale(rule, adu, now_ns)
            if stale is not None:
                reply, job.outcome = stale, cache.outcome()
        cache.failed(adu, reply, now_ns)
        return reply

    def _stale_for_down(self, job: Job) -> bool:
        """A read refused as its unit is down, answered with stale data if its rule allows."""
        rule = job.cache
        reply = None if rule is None else self.cache.stale(rule, job.adu, time.monotonic_ns())
        if reply is None:
            return False
        job.outcome = self.cache.outcome()
        self._deliver(job, reply)
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
        if self._stale_for_down(job):
            return True
        self._counters.demoted_rejects += 1
        job.outcome = Outcome.DEVICE_DOWN
        self._deliver(job, self._failure(job, pdu.GATEWAY_TARGET_FAILED))
        return True

    def _deliver_any(self, job: Job, reply: bytes | None, forwarded: int = -1) -> None:
        """job's outcome to its client (Router.finished), or to the face whose exchange it
        is (its done, on this thread)."""
        exchange = job.exchange
        if exchange is None:
            self._finished(job, reply, forwarded)
        else:
            if reply is not None:
                self._counters.replies += 1     # as the Router counts what it sends
            exchange.done(exchange, reply, job.outcome)

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
        due = self._due_s
        if self._scenarios is None or due is None:
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
        self._inbox = inbox
        self._connections.poll_also(inbox.wake_fd, self._exchanges)

    def _exchanges(self) -> None:
        """Line thread: admit what was submitted, each as a job in its source's queue."""
        inbox = self._inbox
        assert inbox is not None
        self._deliver = self._deliver_any    # outcomes go to clients and faces from now on
        for exchange in inbox.drain():
            try:
                self._admit_exchange(exchange)
            except Exception:   # a bug must cost one request, never the line
                log.exception("internal error admitting %s", exchange.pdu.hex(" "))

    def _admit_exchange(self, exchange: Exchange) -> None:
        """As Router._admit: a line that is down refuses at once (0x0A), an address that is
        down too (0x0B) unless this is its probe; otherwise a job in the source's turn."""
        if type(exchange) is SurveyRead:
            self._admit_survey(exchange)
            return
        counters = self._counters
        counters.requests += 1
        address = exchange.address
        job = Job(None, 0, 0, bytes((address,)) + exchange.pdu, exchange.received_ns,
                  exchange=exchange)
        rule = resolve(exchange.cache, self._cfg.cache)
        if rule is not None and is_read(job.adu):
            job.cache = rule
            reply = self.cache.answer(rule, job.adu, job.received_ns, time.monotonic_ns())
            if reply is not None:
                job.outcome = self.cache.outcome()
                self._deliver(job, reply)
                return
        if self._line is None:
            counters.line_down_rejects += 1
            job.outcome = Outcome.LINE_DOWN
            self._deliver(job, self._failure(job, pdu.GATEWAY_PATH_UNAVAILABLE))
            return
        if self._down[address]:
            if not self.devices.get(address).admit(time.monotonic()):
                if self._stale_for_down(job):
                    return
                counters.demoted_rejects += 1
                job.outcome = Outcome.DEVICE_DOWN
                self._deliver(job, self._failure(job, pdu.GATEWAY_TARGET_FAILED))
                return
            job.probe = True
        self._scheduler.submit(self._queue_of(exchange.source), job)

    def _admit_survey(self, survey: SurveyRead) -> None:
        """An operator's survey read: queued in its own turn whether or not its address is
        down (a probe, never refused as down); the line down tells it at once."""
        job = Job(None, 0, 0, bytes((survey.address,)) + survey.pdu, survey.received_ns,
                  probe=True, exchange=survey)
        if self._line is None:
            survey.done(survey, None, Outcome.LINE_DOWN)
            return
        self._scheduler.submit(self._queue_of(survey.source), job)

    def _survey(self, job: Job, survey: SurveyRead) -> None:
        """One survey read on the line (mbgw.line.survey.ask_once, RTU), after the silence
        the line owes, and t3.5 of quiet after it so that the next transaction keeps the
        rule; nothing is booked, retried or demoted."""
        line, master = self._line, self._master
        assert line is not None and master is not None
        t35_us = line.cfg.t35_us
        reply = None
        try:
            owed_us = (master.quiet_until_ns - time.monotonic_ns()) // 1000
            with self._gate_away():
                answer = ask_once(line, survey.address, survey.pdu, survey.timeout_ms,
                                  max(t35_us, owed_us))
                if answer is None and self._answered_before(survey.address):
                    self._sit_out_late_reply(line, survey.address)
                line.port.wait_quiet(time.monotonic_ns(), t35_us)
            if answer is None:
                outcome = Outcome.TIMEOUT
            else:
                reply, survey.response_ns = answer
                outcome = Outcome.DEVICE_EXCEPTION if reply[0] & pdu.EXCEPTION_FLAG \
                    else Outcome.REPLY
        except SerialError as err:
            self._lost(err)
            outcome = Outcome.LINE_DOWN
        except Exception:   # a bug must cost one read, never the line
            log.exception("internal error on a survey read %s", job.adu.hex(" "))
            outcome = Outcome.ERROR
        survey.done(survey, reply, outcome)

    def _answered_before(self, address: int) -> bool:
        """The line has had a valid answer from address (its devices, looked at without
        adding one)."""
        return any(d.address == address and d.last_success for d in self.devices.all())

    def _sit_out_late_reply(self, line: SerialLine, address: int) -> None:
        """A device the clients use missed a survey read's (short) timeout: RTU has no
        transaction id, so its late reply would answer a client's next request to it.  The
        line listens for it, up to the device's stout, before anything else goes out."""
        until = time.monotonic_ns() + self._timing.stout_ns[address]
        while time.monotonic_ns() < until:
            got = line.port.read_reply(until, line.cfg.end_of_frame_us)
            if got.frame is not None and got.frame[0] == address:
                return

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

    def _withdrawn(self, job: Job) -> bool:
        """An exchange whose source has closed (a TCP client gone: `closed`, read only) does
        not go on the line, as a closed client's queue is discarded; the face is told."""
        exchange = job.exchange
        if exchange is None or not getattr(exchange.source, "closed", False):
            return False
        exchange.done(exchange, None, Outcome.WITHDRAWN)
        return True

    def _queue_of(self, source: Hashable) -> Queue:
        queues = self._queues
        queue = queues.get(source)
        if queue is None:
            if len(queues) >= MAX_SOURCES:     # forget the sources with nothing queued
                for gone in [s for s, q in queues.items() if not q.scheduled]:
                    del queues[gone]
            queue = queues[source] = Queue()
        return queue

    # --- the serial scenarios ---

    def use_scenarios(self, engine: Scenarios) -> None:
        """Run engine's scenarios on this line, and those of the settings to come (called
        once, before start())."""
        self._engine = engine
        engine.health = SerialHealth(self.devices)    # the demotion of direct requests
        self._scenarios = engine if serial_scenarios(self._cfg) else None
        self._connections.poll_also(engine.wake_fd, self._engine_ready)

    def _engine_ready(self) -> None:
        """The engine's eventfd is ready: looked at in the next turn even with no scenario
        (an operator's test)."""
        self._engine_woken = True

    def _scenarios_due(self) -> None:
        """The scenario queue gets a turn while a scenario (or a test) is due; the engine
        also takes the table's changes and marks stale data here."""
        self._engine_woken = False
        engine = self._engine
        assert engine is not None
        self._due_s = due = engine.due_in(time.monotonic())
        if due == 0:
            self._scheduler.scenario_due(time.monotonic_ns())

    def _run_scenario(self) -> None:
        engine = self._engine
        assert engine is not None
        test = engine.take_test(time.monotonic())
        if test is not None:
            self._traced_run(test.scenario, test.pdu, None)
            done = self._exchange(test.scenario, test.pdu)
            engine.test_done(test, *done)
            self._traced_run(test.scenario, test.pdu, done)
            return
        run = engine.next(time.monotonic())
        if run is not None:
            self._traced_run(run.scenario, run.pdu, None)
            done = self._exchange(run.scenario, run.pdu,
                                  lambda: engine.retrying(run.scenario))
            result = engine.done(run, *done)
            self._traced_run(run.scenario, run.pdu, done, result.kind)

    def _traced_run(self, scenario, request: bytes, done: tuple | None,
                    kind: str | None = None) -> None:
        """A scenario's run in the trace: its request (done None), then its reply or none
        (done: _exchange's), marked with the scenario's name."""
        trace = self._trace
        if not trace.active:
            return
        if done is None:
            self._run_started = time.monotonic_ns()
            trace.emit_threadsafe(trace_event("request", scenario, request, ""))
            return
        reply, error, _ = done
        kind = kind or error
        latency_ms = (time.monotonic_ns() - self._run_started) / 1e6
        if reply is None:
            outcome = "broadcast" if scenario.slave == pdu.BROADCAST and kind is None \
                else kind or TIMEOUT
            event = trace_event("no reply", scenario, request[:1], outcome, latency_ms)
        else:
            event = trace_event("reply", scenario, bytes(reply), kind or "ok", latency_ms)
        trace.emit_threadsafe(event)

    def _scenarios_while_down(self, engine: Scenarios) -> None:
        """None runs, but the engine's eventfd is read, changes are taken and data ages
        (stale-after); a test is answered at once."""
        now = time.monotonic()
        engine.due_in(now)
        while (test := engine.take_test(now)) is not None:
            engine.test_done(test, None, PATH_UNAVAILABLE)

    def _exchange(self, scenario, request: bytes, on_retry=None) -> tuple:
        """One run of scenario (request: its PDU) on the line with its retries, address 0 a
        broadcast: (reply PDU or None, None or the engine's error kind, the retries made).
        A reply that did not answer the request (another function, another size) is
        returned for the engine to name; none at all is a timeout."""
        master = self._master
        if master is None:
            return None, PATH_UNAVAILABLE, 0
        device = self.devices.get(scenario.slave)
        retried, foreign = device.retries, _foreign_frames(device)
        master.on_retry = on_retry
        try:
            reply = self._on_line(master, bytes((scenario.slave,)) + request, scenario.retries)
        except LineTimeout as timeout:
            reply = timeout.mismatch
            if reply is None:       # VPGate 8.2: another master's frames came instead
                kind = FRAME_WITHOUT_REQUEST if _foreign_frames(device) > foreign else TIMEOUT
                return None, kind, device.retries - retried
            return reply, None, device.retries - retried
        except SerialError as err:
            self._lost(err)
            return None, PATH_UNAVAILABLE, device.retries - retried
        except Exception:   # a bug must cost one run, never the scenario's schedule
            log.exception("internal error running scenario %s", scenario.name)
            return None, TIMEOUT, device.retries - retried
        finally:
            master.on_retry = None
        if self._caching:
            self._scenario_cached(bytes((scenario.slave,)) + request, reply)
        return reply, None, device.retries - retried

    def _scenario_cached(self, adu: bytes, reply: bytes | None) -> None:
        """A scenario's read that was answered fills the cache; its write drops what it
        overlaps."""
        if is_read(adu):
            if reply is not None and not reply[0] & pdu.EXCEPTION_FLAG:
                self.cache.answered(adu, reply, time.monotonic_ns())
        else:
            self.cache.written(adu)

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


def _foreign_frames(device) -> int:
    """Whole frames heard while waiting for device's reply that were not replies: another
    address's, or a request's shape (another master's request read as a reply)."""
    return device.wrong_unit + device.invalid_frames


def route_caches(cfg: SlaveConfig) -> list:
    """The routes' cache rules: a reload that changes one empties the cache."""
    return [route.cache for route in cfg.routes]


def serial_scenarios(cfg: SlaveConfig) -> tuple:
    """The scenarios this line runs."""
    return tuple(s for s in cfg.scenarios if s.kind == "serial")
