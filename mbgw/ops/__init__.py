"""Running as a service, for both modes: systemd notification, SIGHUP reload and stop
(`service`), the control socket (`control`) with the commands both modes share (`status`),
the trace hub (`trace`), Prometheus metrics (`metrics`), line-wide counters (`counters`),
per-address statistics and health, which also demotes a silent address (`device_stats`),
logging for operators (`log`), the Modbus TCP servers' TLS context, certificate checks and
client roles (`tls`).

Shared between threads: the counters (the line thread writes most, the asyncio thread the
connection counters and resets them), TraceHub.active, the line's up flag, and the
running configuration (replaced whole by a reload).  Each is one attribute read or write,
safe under the GIL; nothing on a request's path waits for this package."""
