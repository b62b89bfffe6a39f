#!/bin/bash
# The built package under its own units, as on a real machine: mbgw.deb installed in a Debian 12
# container booted with systemd (systemd-nspawn --boot, a rootfs made by mmdebstrap from Debian's
# packages), then mbgw.service and mbgw@NAME started, reloaded, restarted (by systemctl and by
# the console) and configured through the web console as an operator would, each check on
# what really happened (the file on disk, the registers read back over Modbus TCP by mbpoll,
# systemd's own view of the units, the journal's records and their audit fields, what a
# Mosquitto broker receives from [mqtt]).
#
# Usage: scripts/container-test.sh [mbgw.deb]          (root; systemd-container, mmdebstrap)
# The rootfs is cached in $MBGW_CI_CACHE (/var/cache/mbgw-ci), keyed by the package's Depends,
# the host's apt sources and RECIPE below; each run boots an overlay on it (or a copy), removed
# at the end, so the cache never changes.
# A machine that cannot boot the container: the test says why and fails when $CI is true (CI
# must show it ran), else it says SKIPPED and exits 0.
set -euo pipefail
RECIPE=2                   # bump when the rootfs below changes
INCLUDE=systemd,dbus,socat,mbpoll,mosquitto,mosquitto-clients
repo=$(cd "$(dirname "$0")/.." && pwd)
deb=$(realpath "${1:-$repo/mbgw.deb}")
cache=${MBGW_CI_CACHE:-/var/cache/mbgw-ci}
work=$(mktemp -d)
nspawn=""
pid1=""
overlay=""
skipped=""
PASSWORD=ci-admin-secret
WATCHDOG_S=30              # WatchdogSec= of the units
DEADLINE_S=60
BROKER_PORT=18830          # the test's own Mosquitto, in the container's own loopback

say() { echo "container: $*"; }
fail() { echo "container: FAIL: $*" >&2; exit 1; }
unable() {
    if [ "${CI:-}" = true ]; then fail "cannot run here (CI=true): $*"; fi
    say "SKIPPED: cannot run here: $*"
    skipped=yes
    exit 0
}

# inside CMD...: run CMD in the container, as root, with a clean environment
inside() {
    nsenter --target "$pid1" --all --wdns=/ \
        env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root LANG=C.UTF-8 "$@"
}

cleanup() {
    local rc=$?
    if [ $rc -ne 0 ] && [ -n "$pid1" ]; then
        echo "--- journal of the units (last 60 lines)" >&2
        inside journalctl --no-pager -n 60 -u mbgw -u 'mbgw@*' -u broker >&2 || true
    fi
    if [ -n "$nspawn" ] && kill -0 "$nspawn" 2>/dev/null; then
        kill -TERM "$nspawn" 2>/dev/null || true      # powers the container off
        for _ in $(seq 100); do kill -0 "$nspawn" 2>/dev/null || break; sleep 0.1; done
        kill -KILL "$nspawn" 2>/dev/null || true
        wait "$nspawn" 2>/dev/null || true
    fi
    [ -z "$overlay" ] || umount "$overlay" || umount -l "$overlay" || rc=1
    rm -rf --one-file-system "$work"        # never into the cached rootfs
    if [ $rc -ne 0 ]; then say "FAILED (rc $rc)"; elif [ -z "$skipped" ]; then say "passed"; fi
    exit $rc
}
trap cleanup EXIT

# wait_for WHAT COMMAND...: retry COMMAND every 0.2 s until it succeeds, for DEADLINE_S
wait_for() {
    local what=$1 tries=$((DEADLINE_S * 5)); shift
    until "$@" >/dev/null 2>&1; do
        tries=$((tries - 1)); [ $tries -gt 0 ] || fail "no $what after ${DEADLINE_S} s"
        sleep 0.2
    done
}

[ "$(id -u)" -eq 0 ] || unable "not root"
for tool in systemd-nspawn mmdebstrap nsenter; do
    command -v "$tool" >/dev/null || unable "no $tool (scripts/setup.sh installs it)"
done
[ -f "$deb" ] || fail "no package $deb"

# --- the rootfs: Debian 12 minbase, systemd, the package's Depends (cached) ----------------
sources=()
for file in /etc/apt/sources.list.d/*.sources /etc/apt/sources.list; do
    [ -f "$file" ] && grep -q '^[^#]' "$file" && sources+=("$file")
done
[ ${#sources[@]} -gt 0 ] || unable "no apt sources on the host"
depends=$(dpkg-deb -f "$deb" Depends)
key=$( { echo "$RECIPE $INCLUDE"; echo "$depends"; cat "${sources[@]}"; } \
    | sha256sum | cut -c1-16)
rootfs=$cache/rootfs-$key
mkdir -p "$cache"
(
    flock 9
    if [ ! -d "$rootfs" ]; then
        say "making the rootfs $rootfs (mmdebstrap)"
        rm -rf "$rootfs.new"
        # the Depends, by apt itself: the rootfs follows the package
        mmdebstrap --quiet --mode=root --variant=minbase --include="$INCLUDE" \
            --customize-hook="chroot \"\$1\" apt-get satisfy -y -q --no-install-recommends \
'$depends'" bookworm "$rootfs.new" "${sources[@]}" >"$cache/mmdebstrap.log" 2>&1 \
            || { tail -20 "$cache/mmdebstrap.log" >&2; fail "mmdebstrap"; }
        mv "$rootfs.new" "$rootfs"
    fi
    touch "$rootfs"
    # other recipes' rootfs, unused for a week
    find "$cache" -mindepth 1 -maxdepth 1 -name 'rootfs-*' -mtime +7 -exec rm -rf {} +
) 9>"$cache/lock"

# --- boot a copy ----------------------------------------------------------------------------
say "boot a copy of $rootfs"
# an overlay on the cached rootfs (its changes go to $work/upper), else a whole copy
mkdir "$work/root" "$work/upper" "$work/overlay-work"
if mount -t overlay overlay -o "lowerdir=$rootfs,upperdir=$work/upper,workdir=$work/overlay-work" \
        "$work/root" 2>/dev/null; then
    overlay=$work/root
else
    cp -a --reflink=auto "$rootfs/." "$work/root"
fi
cp "$deb" "$work/root/root/mbgw.deb"
# --register=no --keep-unit: no host systemd or machined to ask (PID 1 here need not be
# systemd); --private-network: its own loopback, no port clash with the host
systemd-nspawn --quiet --register=no --keep-unit --private-network --console=read-only \
    --boot -D "$work/root" >"$work/console.log" 2>&1 &
nspawn=$!
# the container's init once it runs systemd: a child nspawn forks on its way there is gone
# by the time it is asked for its namespaces
for _ in $(seq 100); do
    pid1=$(pgrep -x -P "$nspawn" systemd | head -1) && [ -n "$pid1" ] && break
    kill -0 "$nspawn" 2>/dev/null || break
    sleep 0.1
done
[ -n "$pid1" ] || { cat "$work/console.log" >&2; unable "systemd-nspawn did not start"; }
# systemctl talks to the container's systemd on its private socket, there once it is up
for _ in $(seq $((DEADLINE_S * 10))); do
    inside test -S /run/systemd/private 2>/dev/null && break
    kill -0 "$nspawn" 2>/dev/null || break
    sleep 0.1
done
state=$(inside timeout 60 systemctl is-system-running --wait 2>&1) || true
case $state in
    running) ;;
    degraded) say "degraded: $(inside systemctl --failed --no-legend --plain | tr '\n' ';')" ;;
    *) tail -30 "$work/console.log" >&2; unable "the container's systemd is '$state'" ;;
esac
say "booted: $(inside systemctl --version | head -1)"

# --- install --------------------------------------------------------------------------------
say "install mbgw.deb"
inside apt-get install -y -q /root/mbgw.deb >"$work/apt.log" 2>&1 \
    || { cat "$work/apt.log" >&2; fail "apt-get install"; }
[ "$(inside stat -c '%U:%G %a' /etc/mbgw)" = "root:mbgw 2775" ] \
    || fail "/etc/mbgw: $(inside stat -c '%U:%G %a' /etc/mbgw), not root:mbgw 2775"
for unit in mbgw.service mbgw@gw2.service; do
    out=$(inside systemd-analyze verify --man=no "$unit" 2>&1) || fail "verify $unit: $out"
    # the exposure level must not grow (2.1; systemd-analyze prints it / 10)
    out=$(inside systemd-analyze security --threshold=21 "$unit" 2>&1) \
        || fail "security $unit: $(tail -1 <<<"$out")"
done

# Two pty pairs for the serial lines, that the units' group dialout can open; no serial slave:
# the checks go to the exchange table (units 247-254) over Modbus TCP.
for n in 0 2 4; do
    inside systemd-run --quiet --unit="pty-mb$n" socat \
        "pty,raw,echo=0,link=/dev/ttyMB$n,group-late=dialout,perm-late=0660" \
        "pty,raw,echo=0,link=/dev/ttyMB$((n + 1))"
done
wait_for "pty pairs" inside test -e /dev/ttyMB0 -a -e /dev/ttyMB2 -a -e /dev/ttyMB4

# --- mbgw.service -----------------------------------------------------------------------------
say "configure and start mbgw.service"
for words in "serial device /dev/ttyMB0" "serial baudrate 19200" "table enabled on" \
             "table persist-interval 1" "web listen 127.0.0.1:8080"; do
    # shellcheck disable=SC2086
    inside mbgw config set $words >/dev/null
done
echo "$PASSWORD" | inside mbgw config password admin --stdin >/dev/null
[ "$(inside stat -c '%U:%G %a' /etc/mbgw/mbgw.toml)" = "root:mbgw 640" ] \
    || fail "mbgw.toml with a password: $(inside stat -c '%U:%G %a' /etc/mbgw/mbgw.toml)"
out=$(inside mbgw config show --security --json | inside python3 -c '
import json, sys
r = json.load(sys.stdin)
f = r["file"]
print(f["owner"], f["group"], f["mode"], f["others_can_read"], r["web"]["users"],
      [(li["name"], li["port"]) for li in r["listeners"] if "port" in li])')
[ "$out" = "root mbgw 0640 False ['admin'] [('modbus', 502)]" ] \
    || fail "mbgw config show --security: $out"
inside systemctl start mbgw || fail "systemctl start mbgw"

show() { inside systemctl show -P "$2" "$1"; }
pid=$(show mbgw MainPID)
[ "$pid" -gt 0 ] || fail "no MainPID"
# user mbgw, group mbgw, and dialout (the units' SupplementaryGroups=) for the serial ports
ids=$(inside grep -E '^(Uid|Gid|Groups):' "/proc/$pid/status" | tr -s '\t\n ' ' ')
u=$(inside id -u mbgw) g=$(inside id -g mbgw) dialout=$(inside getent group dialout | cut -d: -f3)
[[ "$ids" == *"Uid: $u $u $u $u Gid: $g $g $g $g Groups:"*" $dialout "* ]] \
    || fail "the daemon's ids: $ids"

# systemctl status: the daemon's STATUS= line
status_text=$(show mbgw StatusText)
[[ "$status_text" == "slave mode: line up, 0 clients, "* ]] || fail "StatusText: $status_text"

# status_value INSTANCE_OPTIONS... EXPR: a value of `mbgw status --json` (python3 expression on s)
status_value() {
    local expr=${*: -1}
    inside mbgw status --json "${@:1:$#-1}" \
        | inside python3 -c "import json, sys; s = json.load(sys.stdin); print($expr)"
}
[ "$(status_value 's["table"]["persist"]["path"]')" = /var/lib/mbgw/table ] \
    || fail "the default table file under the unit: $(status_value 's["table"]["persist"]')"
inside mbgw status | grep "persist /var/lib/mbgw/table" >/dev/null \
    || fail "mbgw status: no persist line"

say "reload"
inside systemctl reload mbgw || fail "systemctl reload mbgw"
[ "$(show mbgw MainPID)" = "$pid" ] || fail "reload changed the MainPID"

# --- the console's JSON API: Set and Upload write /etc/mbgw/mbgw.toml and apply it ----------
say "the web console: POST /api/config and /api/config/file"
api() {     # api SCRIPT [PORT]: python3 in the container with a logged-in admin session
    inside python3 - "$PASSWORD" "${2:-8080}" <<EOF
import json, sys, urllib.request, urllib.error, http.cookiejar
base = "http://127.0.0.1:" + sys.argv[2]
opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(http.cookiejar.CookieJar()))
def call(path, body=None, csrf=None, raw=False):
    data = None if body is None else (body.encode() if raw else json.dumps(body).encode())
    request = urllib.request.Request(base + path, data=data)
    if not raw:
        request.add_header("Content-Type", "application/json")
    if csrf:
        request.add_header("X-CSRF-Token", csrf)
    try:
        with opener.open(request, timeout=10) as answer:
            text = answer.read().decode()
    except urllib.error.HTTPError as err:
        sys.exit(f"{path}: HTTP {err.code}: {err.read().decode()}")
    return text if raw and body is None else json.loads(text)
csrf = call("/api/login", {"user": "admin", "password": sys.argv[1]})["csrf"]
$1
EOF
}
wait_for "the web console" inside python3 -c \
    'import urllib.request; urllib.request.urlopen("http://127.0.0.1:8080/", timeout=2)'
out=$(api 'change = {"group": "serial", "key": "stout", "value": "700"}
print(json.dumps(call("/api/config", change, csrf)))') \
    || fail "POST /api/config: $out"
grep -q '"ok": true' <<<"$out" || fail "POST /api/config: $out"
inside grep -qx 'stout = 700' /etc/mbgw/mbgw.toml || fail "stout = 700 is not inside the file"
# rewritten by the service: its owner, the mode kept (the hashes stay closed to others)
[ "$(inside stat -c '%U:%G %a' /etc/mbgw/mbgw.toml)" = "mbgw:mbgw 640" ] \
    || fail "the file the service saved: $(inside stat -c '%U:%G %a' /etc/mbgw/mbgw.toml)"
inside mbgw check-config /etc/mbgw/mbgw.toml >/dev/null \
    || fail "check-config (root) of the saved file"
stout_is() { [ "$(status_value 's["serial"]["stout_ms"]')" = "$1" ]; }
wait_for "stout 700 applied" stout_is 700
out=$(api 'text = call("/api/config/file", raw=True)
text = text.replace("stout = 700", "stout = 800")
print(json.dumps(call("/api/config/file", text, csrf, raw=True)))') \
    || fail "POST /api/config/file: $out"
inside grep -qx 'stout = 800' /etc/mbgw/mbgw.toml || fail "the uploaded file is not on disk: $out"
wait_for "stout 800 applied" stout_is 800
[ "$(show mbgw MainPID)" = "$pid" ] || fail "the console's changes restarted the daemon"

# --- the journal: the daemon's lines are native records; the audit events carry their ids ------
say "the journal: audit records of mbgw config set, the console's login and change, the reload"
CONFIG_CHANGED=1ce6a4d2f3db44198e8f659af73c0a8f LOGIN_OK=9be3c857f46d4d9088c84b0c6933833a
# journal_has MATCHES... CONDITION: journalctl -o json MATCHES has a record r for which the
# python3 expression CONDITION holds
journal_has() {
    inside journalctl -o json --no-pager "${@:1:$#-1}" | inside python3 -c "
import json, sys
sys.exit(not any(${*: -1} for r in map(json.loads, sys.stdin)))"
}
wait_for "mbgw config set's record (root, from the CLI)" journal_has MESSAGE_ID=$CONFIG_CHANGED \
    MBGW_SOURCE=cli 'r["MBGW_KEYS"] == "serial.device" and r["_UID"] == "0"
        and r["MBGW_FILE"] == "/etc/mbgw/mbgw.toml" and r["SYSLOG_IDENTIFIER"] == "mbgw"'
wait_for "the console's login record" journal_has MESSAGE_ID=$LOGIN_OK \
    _SYSTEMD_UNIT=mbgw.service 'r["MBGW_USER"] == "admin" and r["MBGW_CLIENT"] == "127.0.0.1"
        and r["PRIORITY"] == "6" and r["_TRANSPORT"] == "journal"'
wait_for "the console's change record" journal_has MESSAGE_ID=$CONFIG_CHANGED \
    _SYSTEMD_UNIT=mbgw.service 'r["MBGW_SOURCE"] == "web" and r["MBGW_KEYS"] == "serial.stout"
        and r["MBGW_USER"] == "web admin@127.0.0.1"'
wait_for "the reload's record" journal_has MESSAGE_ID=$CONFIG_CHANGED _SYSTEMD_UNIT=mbgw.service \
    'r["MBGW_SOURCE"] == "sighup" and "stout" in r["MBGW_KEYS"]'
journal_has _SYSTEMD_UNIT=mbgw.service _TRANSPORT=journal \
    'r["MESSAGE"].startswith("mbgw: slave mode: listening on") and r["MBGW_LOGGER"] == "mbgw"' \
    || fail "the daemon's lines are not native journal records"

say "a wrong file is refused at reload, the running settings kept"
inside cp -p /etc/mbgw/mbgw.toml /root/good.toml
inside sed -i 's/^stout = 800$/stout = 0/' /etc/mbgw/mbgw.toml
inside grep -qx 'stout = 0' /etc/mbgw/mbgw.toml || fail "could not spoil the file"
inside systemctl reload mbgw 2>/dev/null && fail "systemctl reload accepted stout = 0"
[ "$(show mbgw ActiveState)" = active ] \
    || fail "mbgw is $(show mbgw ActiveState) after a refused reload"
[ "$(show mbgw MainPID)" = "$pid" ] || fail "a refused reload changed the MainPID"
stout_is 800 || fail "the running stout changed"
inside cp -p /root/good.toml /etc/mbgw/mbgw.toml
inside systemctl reload mbgw || fail "reload of the good file again"

# --- the console's restart: the daemon exits 75 (RestartForceExitStatus=), systemd starts it ---
# console_restart UNIT PORT: POST /api/restart as the Administration page does; a new process
# and invocation of UNIT, counted by systemd, active again; the journal names who asked
console_restart() {
    local unit=$1 port=$2 old_pid old_id restarts asked out
    old_pid=$(show "$unit" MainPID) old_id=$(show "$unit" InvocationID)
    restarts=$(show "$unit" NRestarts)
    asked=$(date +%s%N)
    out=$(api 'print(call("/api/restart", {}, csrf)["how"])' "$port") \
        || fail "POST /api/restart ($unit): $out"
    [ "$out" = "systemd restarts $unit.service" ] || fail "POST /api/restart ($unit): $out"
    again() {
        local now
        now=$(show "$unit" MainPID)
        [ "$(show "$unit" ActiveState)" = active ] && [ "$now" -gt 0 ] && [ "$now" != "$old_pid" ]
    }
    wait_for "$unit active again after the console's restart" again
    say "$unit: active again $((($(date +%s%N) - asked) / 1000000)) ms after the console's restart"
    [ "$(show "$unit" InvocationID)" != "$old_id" ] || fail "$unit: the same InvocationID"
    [ "$(show "$unit" NRestarts)" = $((restarts + 1)) ] \
        || fail "$unit: NRestarts $(show "$unit" NRestarts), was $restarts"
    wait_for "$unit's journal record of the restart and who asked" journal_has \
        _SYSTEMD_UNIT="$unit.service" _PID="$old_pid" "r[\"PRIORITY\"] == \"6\" and
        \"restart asked (web admin@127.0.0.1): systemd restarts $unit.service\" in r[\"MESSAGE\"]"
}

# --- [table] persist across systemctl restart ------------------------------------------------
say "the exchange table survives systemctl restart"
# poll PORT REGISTER COUNT: the values of holding registers (0-based) of unit 247
poll() {
    inside timeout 10 mbpoll -m tcp -a 247 -p "$1" -0 -t 4 -r "$2" -c "$3" -1 127.0.0.1 \
        | sed -n 's/^\[\([0-9]*\)\]: *\t*\(-\?[0-9]*\).*/\1=\2/p' | tr '\n' ' '
}
inside timeout 10 mbpoll -m tcp -a 247 -p 502 -0 -t 4 -r 4096 -1 127.0.0.1 4660 22136 >/dev/null \
    || fail "mbpoll write to the table"
[ "$(poll 502 4096 2)" = "4096=4660 4097=22136 " ] \
    || fail "read back before restart: $(poll 502 4096 2)"
console_restart mbgw 8080
[ "$(poll 502 4096 2)" = "4096=4660 4097=22136 " ] \
    || fail "after the console's restart: $(poll 502 4096 2)"
inside systemctl restart mbgw || fail "systemctl restart mbgw"
pid=$(show mbgw MainPID)
started=$(show mbgw ExecMainStartTimestampMonotonic)
restarted_at=$(date +%s)
[ "$(poll 502 4096 2)" = "4096=4660 4097=22136 " ] || fail "after restart: $(poll 502 4096 2)"
[ "$(inside stat -c '%U:%G %a' /var/lib/mbgw)" = "mbgw:mbgw 750" ] \
    || fail "/var/lib/mbgw: $(inside stat -c '%U:%G %a' /var/lib/mbgw)"
[ "$(inside stat -c '%U:%G' /var/lib/mbgw/table)" = "mbgw:mbgw" ] || fail "/var/lib/mbgw/table"

# --- a second line added by a reload: a serial master on it reads the table through a route ----
say "a [[line]] in master mode added by systemctl reload; mbpoll, its serial master, reads the table"
inside sh -c 'printf "\n[[line]]\nname = \"panel\"\ndevice = \"/dev/ttyMB4\"\nbaudrate = 19200\n\
format = \"8n1\"\nmode = \"master\"\n\n[[route]]\nfrom = \"panel\"\nunits = \"9\"\ntable = true\n" \
    >> /etc/mbgw/mbgw.toml'
inside mbgw check-config /etc/mbgw/mbgw.toml >/dev/null || fail "check-config with line panel"
inside systemctl reload mbgw || fail "systemctl reload mbgw (line panel added)"
[ "$(show mbgw MainPID)" = "$pid" ] || fail "adding a line restarted the daemon"
wait_for "line panel in mbgw status" inside mbgw status --line panel
# panel_reads: unit 9 on line panel, registers 4096-4097 of the table, as a serial master reads them
panel_reads() {
    [ "$(inside timeout 10 mbpoll -m rtu -b 19200 -d 8 -P none -s 1 -a 9 -0 -t 4 -r 4096 -c 2 \
        -1 /dev/ttyMB5 | sed -n 's/^\[\([0-9]*\)\]: *\t*\(-\?[0-9]*\).*/\1=\2/p' \
        | tr '\n' ' ')" = "4096=4660 4097=22136 " ]
}
wait_for "the table read by a serial master on line panel" panel_reads
inside sh -c "cat /proc/$pid/task/*/comm" | grep -x mbgw-panel >/dev/null \
    || fail "no thread mbgw-panel for line panel"

# --- northbound MQTT as installed: a Mosquitto broker receives the edge node's births ----------
say "[mqtt] set and reloaded: a Mosquitto broker receives the Sparkplug NBIRTH, the JSON status"
# the broker with its own file and port, beside the packaged mosquitto.service on 1883
inside sh -c "printf 'listener $BROKER_PORT 127.0.0.1\nallow_anonymous true\npersistence false\n' \
    > /root/broker.conf"
inside systemd-run --quiet --unit=broker mosquitto -c /root/broker.conf
wait_for "broker on port $BROKER_PORT" inside mosquitto_sub -h 127.0.0.1 -p $BROKER_PORT -t ready -E
for words in "mqtt broker mqtt://127.0.0.1:$BROKER_PORT" "mqtt profile sparkplug" \
             "mqtt group plant1" "mqtt node gw-ci"; do
    # shellcheck disable=SC2086
    inside mbgw config set $words >/dev/null
done
# one scenario; its address answers nothing here, which the node's NBIRTH does not wait for
inside sh -c 'printf "\n[[scenario]]\nname = \"level\"\nslave = 3\nfunction = 3\naddress = 0\n\
quantity = 1\ntable = 0\ncycle = 1000\ntype = \"int16\"\n" >> /etc/mbgw/mbgw.toml'
inside mbgw check-config /etc/mbgw/mbgw.toml >/dev/null || fail "check-config with [mqtt]"
# NBIRTH is not retained: subscribed (SUBACK, seen at once through stdbuf) before the reload
# that starts the edge node
inside stdbuf -oL mosquitto_sub -d -h 127.0.0.1 -p $BROKER_PORT -C 1 -W 20 \
    -t 'spBv1.0/plant1/NBIRTH/#' -F '%t %x' >"$work/nbirth" 2>&1 &
subscriber=$!
wait_for "the NBIRTH subscription" grep -q SUBACK "$work/nbirth"
inside systemctl reload mbgw || fail "systemctl reload mbgw ([mqtt] added)"
[ "$(show mbgw MainPID)" = "$pid" ] || fail "adding [mqtt] restarted the daemon"
wait "$subscriber" || fail "no NBIRTH within 20 s: $(cat "$work/nbirth")"
nbirth=$(grep '^spBv1.0/' "$work/nbirth") || fail "no NBIRTH line: $(cat "$work/nbirth")"
[ "${nbirth%% *}" = spBv1.0/plant1/NBIRTH/gw-ci ] || fail "NBIRTH topic: ${nbirth%% *}"
# decoded by the installed package's own compiled proto, with Debian's python3-protobuf
out=$(inside python3 -c '
import sys
from mbgw.northbound.sparkplug_b_pb2 import Payload
p = Payload()
p.ParseFromString(bytes.fromhex(sys.argv[1]))
print(p.seq, sorted(m.name for m in p.metrics))' "${nbirth#* }") || fail "decode NBIRTH: $out"
[ "$out" = "0 ['Lines/panel/State', 'Lines/serial/State', 'Node Control/Rebirth', 'bdSeq']" ] \
    || fail "NBIRTH: $out"
[ "$(status_value 's["mqtt"]["connected"]')" = True ] \
    || fail "mbgw status: $(status_value 's.get("mqtt")')"

inside mbgw config set mqtt profile json >/dev/null
inside systemctl reload mbgw || fail "systemctl reload mbgw (profile json)"
# json_status: GROUP/NODE/status as a new subscriber gets it: "RETAIN-FLAG PAYLOAD"
json_status() {
    inside mosquitto_sub -h 127.0.0.1 -p $BROKER_PORT -C 1 -W 2 --retained-only \
        -t plant1/gw-ci/status -F '%r %p'
}
json_online() { [ "$(json_status)" = "1 online" ]; }
wait_for "plant1/gw-ci/status retained online" json_online
[ "$(show mbgw MainPID)" = "$pid" ] || fail "the profile's change restarted the daemon"

# --- mbgw@NAME, its own file beside mbgw.service --------------------------------------------
say "mbgw@gw2 with /etc/mbgw/gw2.toml"
inside mbgw config default -i gw2 >/dev/null
echo "$PASSWORD" | inside mbgw config password -i gw2 admin --stdin >/dev/null
for words in "serial device /dev/ttyMB2" "net mdbport 1502" "table enabled on" \
             "web listen 127.0.0.1:8081"; do
    # shellcheck disable=SC2086
    inside mbgw config set -i gw2 $words >/dev/null
done
# a scenario reading a device that is not there (no slave on the pty): only for --save
inside sh -c 'printf "\n[[scenario]]\nname = \"probe\"\nslave = 1\nfunction = 3\naddress = 0\n\
quantity = 1\ntable = 0\ncycle = 1000\n" >> /etc/mbgw/gw2.toml'
inside mbgw check-config /etc/mbgw/gw2.toml >/dev/null || fail "gw2.toml with a scenario"
inside systemctl start mbgw@gw2 || fail "systemctl start mbgw@gw2"
out=$(inside mbgw scenario disable probe --save -i gw2 2>&1) || fail "scenario disable --save: $out"
inside grep -qx 'enabled = false' /etc/mbgw/gw2.toml || fail "--save did not write the file: $out"
[ "$(inside stat -c %U /etc/mbgw/gw2.toml)" = mbgw ] || fail "gw2.toml was not saved by mbgw@gw2"
[ "$(status_value -i gw2 's["table"]["persist"]["path"]')" = /var/lib/mbgw/gw2/table ] \
    || fail "mbgw@gw2's table file: $(status_value -i gw2 's["table"]["persist"]')"
inside timeout 10 mbpoll -m tcp -a 247 -p 1502 -0 -t 4 -r 4096 -1 127.0.0.1 7 >/dev/null \
    || fail "mbpoll write to mbgw@gw2's table"
inside systemctl reload mbgw@gw2 || fail "systemctl reload mbgw@gw2"
inside systemctl restart mbgw@gw2 || fail "systemctl restart mbgw@gw2"
[ "$(poll 1502 4096 1)" = "4096=7 " ] || fail "mbgw@gw2 after restart: $(poll 1502 4096 1)"
console_restart mbgw@gw2 8081
[ "$(poll 1502 4096 1)" = "4096=7 " ] \
    || fail "mbgw@gw2 after the console's restart: $(poll 1502 4096 1)"
[ "$(poll 502 4096 1)" = "4096=4660 " ] || fail "mbgw.service's table changed: $(poll 502 4096 1)"

# --- the watchdog: pinged, so no restart past WatchdogSec -------------------------------------
say "the watchdog: mbgw stays up past WatchdogSec=${WATCHDOG_S}s"
uptime_s() { echo $(($(date +%s) - restarted_at)); }
until [ "$(uptime_s)" -gt $((WATCHDOG_S + 5)) ]; do
    [ "$(show mbgw MainPID)" = "$pid" ] || fail "mbgw was restarted (watchdog?)"
    sleep 1
done
[ "$(show mbgw MainPID)" = "$pid" ] && [ "$(show mbgw NRestarts)" = 0 ] \
    && [ "$(show mbgw ActiveState)" = active ] \
    || fail "after $(uptime_s) s: MainPID $(show mbgw MainPID) (was $pid)," \
            "NRestarts $(show mbgw NRestarts)"
pinged=$(show mbgw WatchdogTimestampMonotonic)
[ "$pinged" -gt $((started + WATCHDOG_S * 1000000)) ] \
    || fail "no watchdog ping after the first ${WATCHDOG_S} s ($pinged, started $started)"

say "stop"
inside systemctl stop mbgw mbgw@gw2 || fail "systemctl stop"
for unit in mbgw mbgw@gw2; do
    [ "$(show $unit Result)" = success ] || fail "$unit stopped with $(show $unit Result)"
done
[ "$(json_status)" = "1 offline" ] || fail "plant1/gw-ci/status after the stop: $(json_status)"

say "purge"
inside apt-get purge -y -q mbgw >"$work/apt.log" 2>&1 || { cat "$work/apt.log" >&2; fail "purge"; }
! inside test -e /var/lib/mbgw || fail "purge left /var/lib/mbgw"
! inside dpkg-statoverride --list /etc/mbgw >/dev/null || fail "purge left the statoverride"
