"""The daemon of each mode command, composed here: the mode's own objects (mbgw.slave.daemon,
mbgw.master.daemon, mbgw.transparent.daemon) run by the one skeleton
(mbgw.gateway.skeleton.serve_mode), with the lines of the other mode's kind: a slave-mode
daemon runs the serial faces of its lines in master mode (mbgw.master's), a master-mode daemon
runs its lines in slave mode as targets (mbgw.slave's LineWorker without TCP clients)."""
import importlib

from mbgw.config.model import MasterConfig, SlaveConfig
from mbgw.gateway.skeleton import serve_mode


def run_slave_mode(cfg: SlaveConfig, reconfigure=None) -> None:
    """mbgw slave's daemon; with a line in master mode, its serial face too."""
    from mbgw.slave.daemon import run_slave
    faces = serial_faces if any(line.is_face for line in cfg.lines) else None
    run_slave(cfg, reconfigure, serve_mode, faces)


def run_master_mode(cfg: MasterConfig, reconfigure=None) -> None:
    """mbgw master's daemon; with a line in slave mode, that line as a target too."""
    from mbgw.master.daemon import run_master
    targets = target_lines if any(line.is_target for line in cfg.lines) else None
    run_master(cfg, reconfigure, serve_mode, targets)


def run_transparent_mode(cfg, reconfigure=None) -> None:
    """mbgw transparent's daemon."""
    from mbgw.transparent.daemon import run_transparent
    run_transparent(cfg, reconfigure, serve_mode)


def serial_faces(cfg: SlaveConfig, routes, inboxes: dict, table) -> list:
    """The serial faces' threads, unstarted: one per line in master mode."""
    serial_face = importlib.import_module("mbgw.master.serial_face")
    return [serial_face.build_face(line, cfg, routes, inboxes, table)
            for line in cfg.lines if line.is_face]


def target_lines(cfg: MasterConfig, inboxes: dict):
    """The lines in slave mode, their threads unstarted, their inboxes added to inboxes."""
    targets = importlib.import_module("mbgw.slave.targets")
    return targets.TargetLines(cfg, inboxes)
