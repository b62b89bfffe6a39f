"""The daemon of `mbgw slave` with its lines: line serial and the target lines (slave mode's
daemon), and the serial faces of the lines in master mode (mbgw.master's, imported only when
the settings have such a line)."""
import importlib

from mbgw.config.model import SlaveConfig
from mbgw.slave.daemon import run_slave


def run_gateway(cfg: SlaveConfig, reconfigure=None) -> None:
    """As run_slave; with a line in master mode, its serial face too."""
    faces = serial_faces if any(line.is_face for line in cfg.lines) else None
    run_slave(cfg, reconfigure, faces)


def serial_faces(cfg: SlaveConfig, routes, inboxes: dict, table, hub=None) -> list:
    """The serial faces' threads, unstarted: one per line in master mode."""
    serial_face = importlib.import_module("mbgw.master.serial_face")
    return [serial_face.build_face(line, cfg, routes, inboxes, table, hub)
            for line in cfg.lines if line.is_face]
