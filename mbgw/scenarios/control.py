"""The operator's scenario commands on the control socket, answered by the runners' engines:
"scenarios" (the status rows), "scenario-enable" / "scenario-disable" ({"name", "save"}:
until the next reload, or also written to the configuration file), "scenario-test"
({"fields": {KEY: VALUE}}: one run on the scenario's runner, its result and data).  Each
request is checked here and answered {"error": why} when it cannot be served."""
import asyncio
import logging
from collections.abc import Callable
from pathlib import Path

from mbgw.audit import operator
from mbgw.config import scenario_text
from mbgw.config.scenario import parse_scenario
from mbgw.config.toml_text import write_atomic
from mbgw.errors import ConfigError
from mbgw.scenarios.report import scenarios_status

log = logging.getLogger("mbgw.scenarios")

TEST_NAME = "test"            # the name of a tested scenario that was given none


def scenario_commands(engines: dict, cfg_path: str | Path | None
                      ) -> dict[str, Callable[[dict], object]]:
    """The control commands of a daemon whose runners' engines are `engines` ({"serial":
    Scenarios, "tcp": Scenarios}; a kind with no runner absent or None), for the control
    server's command dict; cfg_path: the configuration file --save writes (None: none).
    scenario-test's handler is a coroutine function (the control server awaits it): the
    test waits for its runner in a worker thread, not on the loop."""
    def status(request: dict) -> dict:
        return {"scenarios": scenarios_status(engines.values())}

    def enable(request: dict) -> dict:
        return _enable(engines, cfg_path, request, True)

    def disable(request: dict) -> dict:
        return _enable(engines, cfg_path, request, False)

    async def test(request: dict) -> dict:
        try:
            sc = _test_scenario(request)
        except ConfigError as err:
            return {"error": str(err)}
        engine = engines.get(sc.kind)
        if engine is None:
            return {"error": f"this daemon has no runner for {sc.kind} scenarios" +
                    (" (serial scenarios run in slave mode only)" if sc.kind == "serial"
                     else "")}
        log.info("scenario test %s (%s) asked by %s", sc.name, sc.target,
                 operator(request.get("uid")))
        return await asyncio.to_thread(engine.request_test, sc)

    return {"scenarios": status, "scenario-enable": enable, "scenario-disable": disable,
            "scenario-test": test}


def _test_scenario(request: dict):
    fields = request.get("fields")
    if not isinstance(fields, dict):
        raise ConfigError("scenario-test: 'fields' must be an object of KEY: VALUE")
    fields = {"name": TEST_NAME, **fields}
    if "cycle" not in fields and "trigger" not in fields:
        fields["cycle"] = 1000          # a test runs once: its trigger does not matter
    if _function_of(fields) in (1, 2, 3, 4) and "table" not in fields:
        fields["table"] = 0             # a test's read is printed, never stored
    if _function_of(fields) == 23 and "read-table" not in fields:
        fields["read-table"] = 0
    return parse_scenario(fields, "scenario")


def _function_of(fields: dict) -> int | None:
    try:
        return int(str(fields.get("function")), 0)
    except ValueError:
        return None


def _enable(engines: dict, cfg_path, request: dict, on: bool) -> dict:
    name = request.get("name")
    save = request.get("save", False)
    if not isinstance(name, str) or not isinstance(save, bool):
        return {"error": "expected {\"name\": NAME, \"save\": true|false}"}
    found = [e for e in engines.values() if e is not None and name in e.names()]
    if not found:
        known = [n for e in engines.values() if e is not None for n in e.names()]
        return {"error": f"no scenario {name!r}" +
                (f" (scenarios: {', '.join(known)})" if known else " (none configured)")}
    if save:
        problem = _save(cfg_path, name, on)
        if problem:
            return {"error": problem}
    found[0].enable(name, on)
    log.info("scenario %s %s by %s%s", name, "enabled" if on else "disabled",
             operator(request.get("uid")),
             f", saved in {cfg_path}" if save else " until the next reload")
    return {"ok": True, "name": name, "enabled": on, "saved": save}


def _save(cfg_path, name: str, on: bool) -> str | None:
    """Write the scenario's `enabled` to the file; why it could not be, or None."""
    if cfg_path is None:
        return "--save: the daemon was started without a configuration file"
    path = Path(cfg_path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        return f"--save: cannot read {path}: {err.strerror or err}"
    new_text = scenario_text.set_enabled(text, name, on)
    if new_text is None:
        return f"--save: {path} has no scenario {name!r} (was it removed since the last reload?)"
    try:
        write_atomic(path, new_text)
    except OSError as err:
        return f"--save: cannot write {path}: {err.strerror or err}"
    return None
