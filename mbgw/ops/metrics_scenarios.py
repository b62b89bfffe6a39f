"""The scenarios' metric families, from the status's "scenarios" rows
(mbgw.scenarios.report)."""
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

SCENARIO_STATES = ("starting", "running", "error", "disabled")


def scenario_families(rows: list[dict]):
    """The scenarios' families from the status's "scenarios" rows (mbgw.scenarios.report)."""
    runs = CounterMetricFamily("mbgw_scenario_runs", "Runs of each scenario (requests sent, "
                               "retries not counted, and runs skipped while its device was "
                               "down).", labels=["scenario"])
    errors = CounterMetricFamily("mbgw_scenario_errors", "Failed runs of each scenario, by "
                                 "kind (timeout, illegal-address, unexpected-data, "
                                 "connection-lost, device-down, ...).",
                                 labels=["scenario", "kind"])
    retries = CounterMetricFamily("mbgw_scenario_retries", "Requests of each scenario "
                                  "repeated after no valid reply.", labels=["scenario"])
    overruns = CounterMetricFamily("mbgw_scenario_overruns", "Periods a cyclic scenario "
                                   "missed: it ran later than one whole period.",
                                   labels=["scenario"])
    age = GaugeMetricFamily("mbgw_scenario_data_age_seconds", "Seconds since a read "
                            "scenario last stored good data (absent before the first).",
                            labels=["scenario"])
    state = GaugeMetricFamily("mbgw_scenario_state", "1 for each scenario's state (starting, "
                              "running, error, disabled), 0 for the others.",
                              labels=["scenario", "state"])
    for row in rows:
        name = row["name"]
        runs.add_metric([name], row["runs"])
        for kind, n in row["errors"].items():
            errors.add_metric([name, kind], n)
        retries.add_metric([name], row["retries"])
        overruns.add_metric([name], row["overruns"])
        if row.get("data_age_s") is not None:
            age.add_metric([name], row["data_age_s"])
        for each in SCENARIO_STATES:
            state.add_metric([name, each], int(row["state"] == each))
    yield from (runs, errors, retries, overruns, age, state)

