#!/bin/bash
# End-to-end test of the INSTALLED package (root, Debian 12): apt-get install ./mbgw.deb, check
# what it put on the system, then run /usr/bin/mbgw -- from /, with a clean environment, so
# neither the checkout nor pyenv can stand in for it -- between a serial slave that is not our
# code (pymodbus's RTU server, on a socat pty pair) and a TCP client that is not our code
# (mbpoll).  The package is purged at the end, on failure too.
# Usage: scripts/smoke-installed.sh [mbgw.deb]     (needs scripts/setup.sh's .venv for pymodbus)
set -euo pipefail
# Not grep -q after a pipe: it stops at the first match, the writer then dies of SIGPIPE, and
# pipefail fails the step (a longer man page did so).  grep without -q reads everything.
contains() { grep "$@" >/dev/null; }
repo=$(cd "$(dirname "$0")/.." && pwd)
deb=$(realpath "${1:-$repo/mbgw.deb}")
peer_python=$repo/.venv/bin/python
work=$(mktemp -d)
chmod 755 "$work"
pids=()
export DEBIAN_FRONTEND=noninteractive
DEADLINE_S=15

say() { echo "smoke: $*"; }
fail() { echo "smoke: FAIL: $*" >&2; exit 1; }

cleanup() {
    local rc=$?
    for pid in "${pids[@]}"; do kill "$pid" 2>/dev/null || true; done
    wait 2>/dev/null || true
    if dpkg-query -W -f '${Status}' mbgw 2>/dev/null | contains installed; then
        apt-get purge -y -qq mbgw >/dev/null || rc=1
    fi
    rm -rf "$work"
    [ $rc -eq 0 ] && say "passed" || say "FAILED (rc $rc)"
    exit $rc
}
trap cleanup EXIT

# The installed mbgw, as a user would run it: from /, with only the system PATH.
mbgw() { (cd / && env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin LANG=C.UTF-8 /usr/bin/mbgw "$@"); }

# wait_for WHAT COMMAND...: retry COMMAND every 0.1 s until it succeeds, for DEADLINE_S.
wait_for() {
    local what=$1 tries=$((DEADLINE_S * 10)); shift
    until "$@" 2>/dev/null; do
        tries=$((tries - 1)); [ $tries -gt 0 ] || fail "no $what after ${DEADLINE_S} s"
        sleep 0.1
    done
}

say "install $deb"
apt-get install -y -qq "$deb" >/dev/null

say "the package"
[ "$(head -1 /usr/bin/mbgw)" = "#!/usr/bin/python3" ] || fail "/usr/bin/mbgw: not Debian's python3"
version=$(dpkg-query -W -f '${Version}' mbgw)
[ "$(mbgw --version)" = "mbgw, version $version" ] || fail "mbgw --version: $(mbgw --version)"
mbgw slave --help | contains -- "--stout" || fail "mbgw slave --help"
mbgw master --help | contains -- "--tcpto" || fail "mbgw master --help"
mbgw status -h | contains -- "--instance NAME" || fail "mbgw status -h"
out=$(mbgw status -i ttySMOKE 2>&1) && fail "mbgw status -i: a daemon answered"
grep -q "/run/mbgw/ttySMOKE/mbgw.sock" <<<"$out" || fail "mbgw status -i: $out"
(cd / && /usr/bin/python3 -I -c 'import mbgw._ffi') || fail "the C core mbgw._ffi does not import"
dpkg-query -W -f '${Depends}' mbgw | contains python3-prometheus-client \
    || fail "mbgw does not depend on python3-prometheus-client (--metrics)"
dpkg-query -W -f '${Conffiles}\n' mbgw | contains "^ /etc/mbgw/mbgw.toml " \
    || fail "/etc/mbgw/mbgw.toml is not a conffile"
[ "$(stat -c %a /etc/mbgw/mbgw.toml)" = 644 ] || fail "/etc/mbgw/mbgw.toml: mode"
# the service replaces its files there (a temporary file, then a rename): group mbgw writes
[ "$(stat -c '%U:%G %a' /etc/mbgw)" = "root:mbgw 2775" ] \
    || fail "/etc/mbgw: $(stat -c '%U:%G %a' /etc/mbgw), not root:mbgw 2775"
mbgw check-config /etc/mbgw/mbgw.toml
# dialout is the units' grant (SupplementaryGroups=), for the service only
! id -nG mbgw | contains -w dialout || fail "user mbgw is in dialout: the units grant it"
[ "$(getent passwd mbgw | cut -d: -f7)" = /usr/sbin/nologin ] || fail "user mbgw has a shell"
runuser -u mbgw -- /usr/bin/mbgw check-config /etc/mbgw/mbgw.toml >/dev/null \
    || fail "the service user cannot read its configuration"
zcat /usr/share/man/man1/mbgw.1.gz | contains 'mbgw config set' || fail "man page: no commands"
for section in FILES ENVIRONMENT "EXIT STATUS" SIGNALS EXAMPLES "SEE ALSO"; do
    zcat /usr/share/man/man1/mbgw.1.gz | contains "^\.SH \"\?$section\"\?$" \
        || fail "mbgw(1): no $section"
done
zcat /usr/share/man/man5/mbgw.toml.5.gz | contains -F '.SH "[general]"' || fail "mbgw.toml(5)"
for page in /usr/share/man/man1/mbgw.1.gz /usr/share/man/man5/mbgw.toml.5.gz; do
    out=$(LC_ALL=C.UTF-8 MANWIDTH=80 man --warnings -l "$page" 2>&1 >/dev/null) \
        || fail "man -l $page: $out"
    [ -z "$out" ] || fail "man -l $page: $out"
done
for unit in mbgw.service mbgw@.service; do
    [ -f "/lib/systemd/system/$unit" ] || fail "$unit not installed"
done
[ ! -e /etc/systemd/system/multi-user.target.wants/mbgw.service ] || fail "enabled on install"

say "systemd-analyze verify, security"
for unit in /lib/systemd/system/mbgw.service /lib/systemd/system/mbgw@.service \
            /lib/systemd/system/mbgw@ttyUSB1.service; do
    out=$(systemd-analyze verify --man=no "$unit" 2>&1) || fail "verify $unit: $out"
    [ -z "$out" ] || fail "verify $unit: $out"
done
for unit in mbgw.service mbgw@.service; do
    for setting in WatchdogSec=30s ProtectProc=invisible ProcSubset=pid \
                   "SystemCallFilter=~@privileged @resources" SupplementaryGroups=dialout \
                   ProtectSystem=strict ReadWritePaths=/etc/mbgw StateDirectoryMode=0750; do
        grep -qx -- "$setting" "/lib/systemd/system/$unit" || fail "$unit: no $setting"
    done
done
# The exposure level (0..100; `systemd-analyze security` prints it divided by 10) must not
# grow: 21 with the units' sandboxing.
cp /lib/systemd/system/mbgw@.service "$work/mbgw@ttyUSB1.service"
for unit in /lib/systemd/system/mbgw.service "$work/mbgw@ttyUSB1.service"; do
    out=$(systemd-analyze security --offline=true --threshold=21 "$unit" 2>&1) \
        || fail "security $unit: $(tail -1 <<<"$out")"
done

say "mbgw config: an unprivileged user is told to use sudo; root changes the conffile"
out=$(runuser -u nobody -- /usr/bin/mbgw config set serial stout 700 2>&1) && fail "nobody wrote"
grep -q "sudo mbgw config set serial stout 700" <<<"$out" || fail "no sudo hint: $out"
mbgw config set serial stout 700 >/dev/null
[ "$(mbgw config show serial stout)" = 700 ] || fail "config set/show"
mbgw check-config /etc/mbgw/mbgw.toml >/dev/null

say "end to end: mbpoll -> /usr/bin/mbgw -> pymodbus RTU slave on a pty"
socat pty,raw,echo=0,link="$work/ttyGW" pty,raw,echo=0,link="$work/ttyDEV" 2>"$work/socat.log" &
pids+=($!)
wait_for "pty pair" test -e "$work/ttyGW" -a -e "$work/ttyDEV"
"$peer_python" -u "$repo/tests/peers/pymodbus_slave.py" "$work/ttyDEV" >"$work/peer.log" 2>&1 &
pids+=($!)
wait_for "READY from the pymodbus slave" grep -qx READY "$work/peer.log"

# start_gateway NAME ARGS...: /usr/bin/mbgw in the background, ready when it tells systemd so
# (READY=1 on $NOTIFY_SOCKET, received here by socat).
start_gateway() {
    local name=$1; shift
    socat -u UNIX-RECV:"$work/notify-$name" CREATE:"$work/notified-$name" &
    pids+=($!)
    wait_for "notify socket" test -S "$work/notify-$name"
    # RUNTIME_DIRECTORY: where the control socket goes, as systemd's RuntimeDirectory= gives it
    mkdir "$work/run-$name"
    # WATCHDOG_USEC: WatchdogSec=2s, so WATCHDOG=1 comes every second
    (cd / && exec env -i PATH=/usr/bin:/bin LANG=C.UTF-8 NOTIFY_SOCKET="$work/notify-$name" \
        WATCHDOG_USEC=2000000 RUNTIME_DIRECTORY="$work/run-$name" /usr/bin/mbgw "$@") \
        >"$work/$name.log" 2>&1 &
    gateway=$!
    pids+=($gateway)
    wait_for "READY=1 from mbgw $name ($(cat "$work/$name.log"))" \
        grep -q READY=1 "$work/notified-$name"
}

# poll PORT: three holding registers of slave 17 through the gateway
poll() {
    local out
    out=$(timeout 10 mbpoll -m tcp -a 17 -p "$1" -0 -t 4 -r 0 -c 3 -1 127.0.0.1) \
        || fail "mbpoll on port $1: $out"
    grep -q $'\[0\]: \t100' <<<"$out" && grep -q $'\[2\]: \t102' <<<"$out" \
        || fail "mbpoll on port $1 read: $out"
}

# scrape_one_reply: /metrics (port 9502) counts one reply from slave 17
scrape_one_reply() {
    local text
    text=$(/usr/bin/python3 -c 'import urllib.request
print(urllib.request.urlopen("http://127.0.0.1:9502/metrics", timeout=10).read().decode())') \
        && grep -Eq '^mbgw_device_replies_total\{(address="17",line="serial"|line="serial",address="17")\} 1(\.0)?$' <<<"$text"
}

stop_gateway() {
    kill -TERM "$gateway"
    wait "$gateway" || fail "mbgw $1 exited with $? on SIGTERM: $(cat "$work/$1.log")"
}

# The owner's way: options on the command line (the installed conffile gives the rest).
start_gateway cli slave --device "$work/ttyGW" --mdbport 1502 --bind 127.0.0.1 \
    --metrics 127.0.0.1:9502
poll 1502
wait_for "slave 17's reply in /metrics (Debian's prometheus_client)" scrape_one_reply
mbgw status --control "$work/run-cli/mbgw.sock" >/dev/null || fail "mbgw status"
wait_for "WATCHDOG=1 from mbgw cli" grep -q WATCHDOG=1 "$work/notified-cli"
wait_for "STATUS= from mbgw cli" grep -q "STATUS=slave mode: line up, 0 clients, 1 requests" \
    "$work/notified-cli"
stop_gateway cli

# The service's way: `mbgw run` with a file written by `mbgw config set`.
conf=$work/gw.toml
for words in "serial device $work/ttyGW" "serial baudrate 19200" "net mdbport 1503" \
             "net bind 127.0.0.1"; do
    # shellcheck disable=SC2086
    mbgw config set --config "$conf" $words >/dev/null
done
mbgw check-config "$conf" >/dev/null
start_gateway run run --config "$conf"
poll 1503
stop_gateway run

say "purge"
apt-get purge -y -qq mbgw >/dev/null
[ ! -e /usr/bin/mbgw ] && [ ! -e /etc/mbgw/mbgw.toml ] || fail "purge left files"
! dpkg-statoverride --list /etc/mbgw >/dev/null || fail "purge left the statoverride of /etc/mbgw"
