"""`python tests/integration/lines_runner.py SPEC slave ...`: mbgw's slave command with the lines
and routes of the JSON file SPEC added to its settings (read again at each reload), for the
tests of many lines until the configuration file's [[line]] and [[route]] tables are parsed.

SPEC: {"lines": [{"name", "device", "mode"?, "baudrate"?, "stout"?, "retries"?}],
       "routes": [{"units": "32-63", "line"? | "table"? | "server"? ["host", port],
                   "offset"?, "address"?}]}
"""
import dataclasses
import importlib
import json
import sys

from mbgw.cli import main
from mbgw.config.lines import LineConfig, RouteConfig
from mbgw.config.model import SerialConfig

SPEC = sys.argv.pop(1)
slave_command = importlib.import_module("mbgw.cli.slave")   # the module, not the command
make_config = slave_command.slave_config


def units(text: str) -> tuple[int, ...]:
    found: list[int] = []
    for part in text.split(","):
        low, _, high = part.partition("-")
        found.extend(range(int(low), int(high or low) + 1))
    return tuple(found)


def with_lines(*args, **kwargs):
    cfg = make_config(*args, **kwargs)
    with open(SPEC) as f:
        spec = json.load(f)
    lines = tuple(LineConfig(line["name"], SerialConfig(device=line["device"],
                                                        baudrate=line.get("baudrate", 19200),
                                                        stout_ms=line.get("stout", 500)),
                             mode=line.get("mode", "slave"), retries=line.get("retries", 0))
                  for line in spec.get("lines", ()))
    routes = tuple(RouteConfig(index, units(route["units"]), line=route.get("line"),
                               table=route.get("table", False),
                               server=tuple(route["server"]) if "server" in route else None,
                               offset=route.get("offset", 0), address=route.get("address"))
                   for index, route in enumerate(spec.get("routes", ()), 1))
    return dataclasses.replace(cfg, lines=lines, routes=routes)


slave_command.slave_config = with_lines
main()
