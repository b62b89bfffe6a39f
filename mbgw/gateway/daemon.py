"""The daemon of each mode command, composed here: the mode's own objects (mbgw.slave.daemon,
mbgw.master.daemon, mbgw.transparent.daemon) run by the one skeleton
(mbgw.gateway.skeleton.serve_mode), with the lines of the other mode's kind: a slave-mode
daemon runs the serial faces of its lines in master mode (mbgw.master's), a master-mode daemon
runs its lines in slave mode as targets (mbgw.slave's SlaveLineThread without TCP clients) and,
when routes take TCP units, the Modbus TCP face (mbgw.slave's listener and router on a thread
of the face's own)."""
import importlib
from functools import partial

from mbgw.config.model import MasterConfig, SlaveConfig
from mbgw.gateway.skeleton import serve_mode
from mbgw.ops.restart import Restart


def run_slave_mode(cfg: SlaveConfig, reconfigure=None) -> None:
    """mbgw slave's daemon; its lines in master mode as serial faces too."""
    from mbgw.slave.daemon import run_slave
    restart = Restart()
    run_slave(cfg, reconfigure, partial(serve_mode, restart=restart), serial_faces,
              monitor_lines)
    restart.finish()


def run_master_mode(cfg: MasterConfig, reconfigure=None) -> None:
    """mbgw master's daemon; its lines in slave mode as targets too."""
    from mbgw.master.daemon import run_master
    restart = Restart()
    run_master(cfg, reconfigure, partial(serve_mode, restart=restart), target_lines, tcp_face,
               monitor_lines)
    restart.finish()


def run_transparent_mode(cfg, reconfigure=None) -> None:
    """mbgw transparent's daemon."""
    from mbgw.transparent.daemon import run_transparent
    restart = Restart()
    run_transparent(cfg, reconfigure, partial(serve_mode, restart=restart))
    restart.finish()


def serial_faces(cfg: SlaveConfig, inboxes: dict, table, hub=None):
    """The serial faces of the lines in master mode (master.faces.LineFaces), unstarted;
    imported only for a daemon that has such a line.  hub: the daemon's trace hub."""
    faces = importlib.import_module("mbgw.master.faces")
    return faces.LineFaces(cfg, inboxes, table, hub)


def target_lines(cfg: MasterConfig, inboxes: dict, hub=None):
    """The lines in slave mode, their threads unstarted, their inboxes added to inboxes.
    hub: the daemon's trace hub."""
    targets = importlib.import_module("mbgw.slave.targets")
    return targets.TargetLines(cfg, inboxes, hub)


def monitor_lines(cfg: SlaveConfig | MasterConfig, table, hub):
    """The lines in monitor mode (monitor.lines.MonitorLines), unstarted; None when there are
    none.  Neither face nor target: they take no request, they store what they hear."""
    if not any(line.is_monitor for line in cfg.lines):
        return None
    lines = importlib.import_module("mbgw.monitor.lines")
    return lines.MonitorLines(cfg, table, hub)


def tcp_face(cfg: MasterConfig, inboxes: dict, table, hub):
    """A master-mode daemon's Modbus TCP face (slave.tcp_face.TcpFace), not listening yet;
    None while no route takes TCP units."""
    face = importlib.import_module("mbgw.slave.tcp_face")
    if not face.has_tcp_face(cfg):
        return None
    return face.TcpFace(cfg, inboxes, table, hub)
