#!/bin/sh
# One-time set-up on Debian 12 (run as root or through sudo): system packages, the
# development venv with the test peers, and the C core built in place.
set -eu
cd "$(dirname "$0")/.."

SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
export DEBIAN_FRONTEND=noninteractive

$SUDO apt-get update -qq
# Build-Depends of debian/control (compiler, libmodbus-dev, python3-dev, debhelper, ...)
$SUDO apt-get build-dep -y -qq ./
# What the tests use besides: socat (pty pairs), mbpoll (a real Modbus client), lintian,
# systemd for systemd-analyze (scripts/smoke-installed.sh), and tshark (decodes the pcap of
# mbgw trace; its debconf question on non-root capture takes the default, no, unasked), and
# openssl (the TLS tests make their certificates with it), sslscan (what port 802 offers), and
# chromium with its driver (the web console's browser tests drive it through selenium), and
# systemd-container and mmdebstrap (scripts/container-test.sh boots the package under systemd
# in a Debian 12 container; without recommends: libnss-mymachines would edit the host's
# nsswitch.conf), and AFL++ with clang's sanitizer runtime (scripts/fuzz.sh: afl-clang-fast
# with AddressSanitizer), and clang-format (.ci/run checks csrc/ and fuzz/ against .clang-format),
# and mosquitto with its clients (the northbound MQTT tests start Debian's broker on a free port
# of 127.0.0.1, and the README's worked example subscribes with mosquitto_sub), and strace (a
# monitor line's test reads the order of its tty's system calls: DTR and RTS lowered first)
$SUDO apt-get install -y -qq --no-install-recommends python3-venv socat mbpoll lintian systemd \
    tshark openssl sslscan chromium chromium-driver systemd-container mmdebstrap afl++ \
    libclang-rt-14-dev clang-format mosquitto mosquitto-clients strace

# Debian's own python3, the interpreter the .deb runs on (never a pyenv shim).
/usr/bin/python3 -m venv .venv
.venv/bin/pip install -q --upgrade pip
.venv/bin/pip install -q -e '.[test]'
echo "set-up done: run the tests with  scripts/test.sh"
