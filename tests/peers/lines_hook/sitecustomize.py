"""`mbgw master` with more lines and routes than its options give, for the tests of serial
faces: put this directory on PYTHONPATH and the lines and routes, as JSON, in
$MBGW_TEST_LINES; run_master then runs with them added to its settings.

{"lines": [{"name": "panel", "device": PATH, "baudrate": 19200, "mode": "master"}, ...],
 "routes": [{"units": [1, 2], "from": "serial", "server": ["127.0.0.1", 1502],
             "offset": 10}, {"units": [30], "from": "serial", "table": true}, ...]}

(The configuration file's [[line]] and [[route]] tables give the same settings; the tests
do not depend on how the file is read.)"""
import os

if os.environ.get("MBGW_TEST_LINES"):
    import dataclasses
    import json

    import mbgw.master.daemon as daemon
    from mbgw.config.lines import LineConfig, RouteConfig
    from mbgw.config.model import SerialConfig

    _given = json.loads(os.environ["MBGW_TEST_LINES"])
    _run_master = daemon.run_master

    def _line(spec: dict) -> LineConfig:
        return LineConfig(spec["name"], SerialConfig(spec["device"],
                                                     baudrate=spec.get("baudrate", 9600)),
                          mode=spec.get("mode", "slave"))

    def _route(index: int, spec: dict) -> RouteConfig:
        server = spec.get("server")
        return RouteConfig(index, tuple(spec["units"]), face=spec.get("from", ""),
                           line=spec.get("line"), table=spec.get("table", False),
                           server=tuple(server) if server else None,
                           offset=spec.get("offset", 0), address=spec.get("address"))

    def run_master(cfg, reconfigure=None):
        cfg = dataclasses.replace(
            cfg, lines=tuple(_line(s) for s in _given.get("lines", ())),
            routes=tuple(_route(i, s) for i, s in enumerate(_given.get("routes", ()), 1)))
        return _run_master(cfg, reconfigure)

    daemon.run_master = run_master
