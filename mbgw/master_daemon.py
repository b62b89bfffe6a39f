"""Runs master mode: opens the line, serves the serial master, tells systemd it is ready,
stops on a signal."""
import asyncio
import logging
import signal

from mbgw.config import MasterConfig
from mbgw.counters import MasterCounters
from mbgw.daemon import sd_notify
from mbgw.serial_port import SerialLine
from mbgw.serial_slave import SerialSlave

log = logging.getLogger("mbgw")


def run_master(cfg: MasterConfig) -> None:
    """Raises SerialError when the device cannot be opened; otherwise returns after SIGTERM
    or SIGINT."""
    counters = MasterCounters()
    line = SerialLine(cfg.serial)
    try:
        slave = SerialSlave(cfg, line, counters)
    except BaseException:
        line.close()
        raise
    try:
        asyncio.run(_serve(cfg, slave, counters))
    finally:
        slave.close()


async def _serve(cfg: MasterConfig, slave: SerialSlave, counters: MasterCounters) -> None:
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(signum, stop.set)
    slave.start()
    s = cfg.serial
    log.info("master mode: serial %s %d %s %s %s; servers' port %d, tcpto %d ms, exception %s, "
             "at most %d connections; slaveid %s", s.device, s.baudrate, s.format, s.protocol,
             s.interface, cfg.mdbport, cfg.tcpto_ms, "on" if cfg.exception else "off",
             cfg.max_connections, cfg.slaveid)
    if not cfg.slaveid.ranges:
        log.warning("the slaveid table is empty: every request on the line is ignored")
    sd_notify("READY=1")

    await stop.wait()
    sd_notify("STOPPING=1")
    log.info("stopping")
    slave.stop()
    await asyncio.to_thread(slave.join)
    log.info("stopped; counters: %s",
             " ".join(f"{k}={v}" for k, v in counters.snapshot().items()))
