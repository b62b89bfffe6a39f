"""Running as a service, for every mode: systemd, reloads, the control socket, status, the
trace hub, metrics, counters, device health and demotion, logging.  Nothing on a request's
path waits for this package; what the threads share here is one attribute read or write
each (counters, TraceHub.active, the running configuration, replaced whole).

May import net, protocol, config, besides errors and audit.
See docs/architecture.md#the-packages.
"""
