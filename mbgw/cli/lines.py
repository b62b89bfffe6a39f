"""A mode command's [[line]] and [[route]] settings: the lines built like [serial] (the same
serial_config and demotion), then the lines and routes checked together with line serial."""
import dataclasses

import click

from mbgw.cli.serial_options import demotion, serial_config
from mbgw.config import line_file
from mbgw.config.lines import LineConfig
from mbgw.config.model import MasterConfig, SlaveConfig
from mbgw.config.monitor import monitor_problems
from mbgw.config.route_checks import config_problems
from mbgw.config.route_plan import daemon_lines

SERIAL_PARAMS = ("device", "protocol", "baudrate", "line_format", "interface", "rtsdelays",
                 "stout", "silence", "ascii_timeout", "nocheck", "dtr", "rts", "cts",
                 "xonxoff", "interframe_silence")
SLAVE_LINE_PARAMS = {"retries": "retries", "turnaround": "turnaround_ms",
                     "late_window": "late_window_ms", "cache": "cache"}


def line_config(table: line_file.LineTable,
                serial_defaults: SlaveConfig | MasterConfig | None = None) -> LineConfig:
    """One [[line]]; click.BadParameter naming it when its settings do not go together.  A
    remote line (connect) takes what its table leaves out of stout, retries and demotion from
    serial_defaults' [serial]."""
    params = table.params
    if table.remote is not None:
        params = _remote_params(table, serial_defaults)
    try:
        serial = serial_config(**{name: params[name] for name in SERIAL_PARAMS
                                  if name in params})
        line_demotion = demotion(params["down_after"], params["probe_interval"])
    except click.BadParameter as err:
        key = str(err.param_hint or "").strip("'").removeprefix("--")   # "'--rts'": rts
        where = f"line {table.name}.{key}" if key else f"line {table.name}"
        raise click.BadParameter(f"{where}: {err.message}") from None
    own = {field: params[name] for name, field in SLAVE_LINE_PARAMS.items()
           if params.get(name) is not None}
    return LineConfig(table.name, serial, mode=table.mode, demotion=line_demotion,
                      remote=table.remote, connect_delay_ms=table.connect_delay_ms, **own)


def _remote_params(table: line_file.LineTable,
                   cfg: SlaveConfig | MasterConfig | None) -> dict:
    """A remote line's parameters: its URL as the device (status shows it, and no two lines
    may share one), its framing as the protocol, pause as the silence before each request,
    and [serial]'s timing where its table gives none."""
    assert table.remote is not None
    params = dict(table.params, device=table.remote.url, interframe_silence=table.pause_ms,
                  protocol="ascii" if table.remote.kind == "ascii-over-tcp" else "rtu")
    if isinstance(cfg, SlaveConfig):
        given = table.keys
        inherited = {"stout": cfg.serial.stout_ms, "retries": cfg.retries,
                     "down-after": cfg.demotion.down_after,
                     "probe-interval": cfg.demotion.probe_interval_ms}
        for key in line_file.SERIAL_DEFAULTS:
            if key not in given:
                params[key.replace("-", "_")] = inherited[key]
    return params


def with_lines(cfg: SlaveConfig | MasterConfig, mode: str, lines=(), routes=(), monitors=(),
               devices=()):
    """cfg with the file's lines, routes, monitor maps and devices, checked (and the gateway
    unit against the implicit routes): click.BadParameter with the first problem, which names
    its line, route, map or device and key."""
    if lines or routes or monitors or devices:
        cfg = dataclasses.replace(cfg, lines=tuple(line_config(t, cfg) for t in lines),
                                  routes=tuple(routes), monitors=tuple(monitors),
                                  devices=tuple(devices))
    elif not cfg.gateway_unit:
        return cfg
    problems = config_problems(cfg, mode)
    problems += monitor_problems(cfg.monitors, {line.name: line.mode
                                                for line in daemon_lines(cfg, mode)})
    if problems:
        raise click.BadParameter(problems[0])
    return cfg
