#!/bin/sh
# The whole suite, as README and .ci/run run it: two passes of .venv/bin/python -m pytest.
# Most tests wait on the gateway's timers and its peers' I/O rather than the CPU (two workers
# kept two CPUs half busy), so three pytest-xdist workers share them (tests/harness.py gives
# each worker its own ports); the tests marked serial hold the gateway or a peer to a few
# milliseconds, or count what it did in a given time, which another worker's load could
# stretch, so they run alone afterwards.  Extra arguments go to both
# passes (a pass that selects no test is no failure).
set -u
cd "$(dirname "$0")/.."
# Every gateway, peer and mbgw command a test starts is a Python process: let them keep their
# bytecode (and pytest its rewritten test modules) rather than compile mbgw again each time.
unset PYTHONDONTWRITEBYTECODE
status=0
run() {
    .venv/bin/python -m pytest "$@" || { rc=$?; [ "$rc" -eq 5 ] || status=$rc; }
}
run -n 3 -m "not serial" "$@"
# A serial test holds a gateway or a peer, so it lives in tests/integration or tests/component:
# without arguments the second pass collects only those (the unit tests again cost it 7 s).
[ "$#" -gt 0 ] || set -- tests/integration tests/component
run -m serial "$@"
exit "$status"
