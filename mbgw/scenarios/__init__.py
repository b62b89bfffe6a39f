"""Scenarios (issue 15, VPGate §3.5, §3.6.3): requests the gateway sends on its own to serial
slaves and Modbus TCP servers, cyclically or when table data changes, keeping their data in
the exchange table.

`plan` orders the runs (VPGate's rules, pure); `exchange` builds a scenario's request from the
table and checks and stores its reply; `engine.Scenarios` is one runner's set (the serial
line's in slave mode, the TCP runner's in every mode): schedule, results, state, counters,
stale data; `report` and `control` are the operator's side (status, metrics, the control
commands); `tcp_runner` runs the TCP scenarios through mbgw.upstream's pool, in a thread of
its own.  The settings are mbgw.config.scenario.

A runner's loop (the serial line worker, the TCP runner):
    poll(its own fds + engine.wake_fd, timeout = engine.due_in(now))
    test = engine.take_test(now)        -> run test.pdu, engine.test_done(test, reply, err, n)
    run = engine.next(now[, can_run])   -> run run.pdu for run.scenario (retries =
                                           run.scenario.retries; slave 0: a broadcast, no
                                           reply), engine.done(run, reply | None, err | None, n)
The daemon: engines = {"serial": Scenarios(cfg.scenarios, table, "serial"), "tcp": ...};
control commands += scenario_commands(engines, cfg.config_file); status["scenarios"] =
scenarios_status(engines.values()); collector.scenarios = that same function; on reload
engine.reconfigure(new.scenarios); the table is on when cfg.table_on.
May import table, upstream, line, ops, protocol, config, errors."""
