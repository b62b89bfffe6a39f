"""A client lent to a Modbus TCP remote line's thread (mbgw.slave.loans): once its request to
the line is answered and it has nothing else in the gateway, its next requests for the line go
from its socket to the device and back on that thread, in C.  What must hold: each reply
answers the request it comes back to; whatever the line does not take (another unit, more than
one request, a failure) is the face's as before; the firewall and the routes of a reload hold
for a lent client; the books are kept.

Peers that are not ours: the single-connection device emulator
(tests/peers/single_client_device.py), a pymodbus RTU slave on line serial's pty, raw
clients and pymodbus's TCP client in front.
"""
import os
import signal
import struct
import threading

import pytest
from pymodbus.client import ModbusTcpClient

from tests.integration.lines.conftest import INVERTER, STOUT_MS
from tests.integration.lines.test_remote_lines import counter, pymodbus_reads, reply
from tests.modbus import mbap, read_holding
from tests.ops import wait_for, wait_for_log
from tests.peers.single_client_device import LATE_REGISTER

pytestmark = pytest.mark.integration

SERIAL_SLAVE = 5              # the pymodbus slave on line serial (units 1-31)
UNROUTED = 60


def inverter_row(s: dict) -> dict:
    return next(r for r in s["lines"] if r["name"] == "inverter")


def reload(gw, path, old: str, new: str) -> None:
    path.write_text(path.read_text().replace(old, new))
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, "configuration reloaded")


def test_a_lent_clients_requests_are_answered_and_booked(remote_gateway, client, device):
    d = device(delays=(0.001, 0.003))
    gw = remote_gateway(d.url)
    c = client(gw)
    for n in range(30):
        assert c.ask(INVERTER + n % 3, read_holding(n, 2)) == reply(n, 2)
    assert d.requests == [(INVERTER + n % 3, read_holding(n, 2)) for n in range(30)]
    s = wait_for(gw, lambda s: counter(s, "replies") == s["counters"]["replies"] == 30,
                 "the line's and the face's books of 30 replies")
    assert counter(s, "requests") == 30 and counter(s, "timeouts") == 0
    assert s["counters"]["requests"] == 30
    (row,) = s["clients"]
    assert (row["requests"], row["in_flight"]) == (30, 0)
    answered = {d["address"]: d for d in inverter_row(s)["devices"]}
    assert answered[INVERTER]["transactions"] == 10
    assert (d.connections, d.resets) == (1, 0)


def test_a_lent_client_asking_elsewhere_is_the_faces_again(remote_gateway, client, device):
    d = device(delays=(0.001, 0.002))
    gw = remote_gateway(d.url)
    c = client(gw)
    assert c.ask(INVERTER, read_holding(0, 1)) == reply(0, 1)
    assert c.ask(SERIAL_SLAVE, read_holding(0, 1))[0] == 0x03     # line serial's slave
    assert c.ask(INVERTER, read_holding(1, 1)) == reply(1, 1)
    assert c.ask(UNROUTED, read_holding(0, 1)) == b"\x83\x0a"
    assert c.ask(INVERTER, read_holding(2, 1)) == reply(2, 1)
    assert [unit for unit, _ in d.requests] == [INVERTER] * 3


def test_pipelined_requests_of_a_lent_client_each_get_their_reply(remote_gateway, client, device):
    d = device(delays=(0.001, 0.005))
    gw = remote_gateway(d.url)
    c = client(gw)
    assert c.ask(INVERTER, read_holding(0, 1)) == reply(0, 1)
    c.send(*(mbap(tid, INVERTER, read_holding(tid, 2)) for tid in (11, 12, 13)))
    assert sorted(c.recv() for _ in range(3)) == \
        [(tid, INVERTER, reply(tid, 2)) for tid in (11, 12, 13)]
    assert c.ask(INVERTER, read_holding(4, 1)) == reply(4, 1)
    assert len(d.requests) == 5


def test_a_rule_a_reload_adds_holds_for_a_lent_client(tmp_path, remote_gateway, client, device):
    d = device(delays=(0.001, 0.002))
    gw = remote_gateway(d.url, rules="\n")
    c = client(gw)
    assert c.ask(INVERTER, read_holding(0, 1)) == reply(0, 1)
    reload(gw, tmp_path / "mbgw.toml", "\n\n",
           '\n[[rule]]\nclient = "127.0.0.1"\nread-only = true\n')
    assert c.ask(INVERTER, bytes.fromhex("06 0001 1234")) == b"\x86\x01"
    assert c.ask(INVERTER, read_holding(1, 1)) == reply(1, 1)
    assert d.requests == [(INVERTER, read_holding(0, 1)), (INVERTER, read_holding(1, 1))]


def test_a_reload_that_routes_the_unit_elsewhere_takes_the_next_request(
        tmp_path, remote_gateway, client, device):
    d = device(delays=(0.001, 0.002))
    gw = remote_gateway(d.url)
    c = client(gw)
    assert c.ask(INVERTER, read_holding(0, 1)) == reply(0, 1)
    from_slave = c.ask(SERIAL_SLAVE, read_holding(0, 1))
    assert c.ask(INVERTER, read_holding(0, 1)) == reply(0, 1)
    reload(gw, tmp_path / "mbgw.toml", 'units = "40-49"\nline = "inverter"',
           f'units = "40-49"\nline = "serial"\naddress = {SERIAL_SLAVE}')
    assert c.ask(INVERTER, read_holding(0, 1)) == from_slave
    assert len(d.requests) == 2


@pytest.mark.serial
def test_a_lent_request_that_times_out_gets_0x0b_and_the_next_its_own_reply(
        remote_gateway, client, device):
    d = device(delays=(0.001, 0.002), late_s=STOUT_MS / 1000 + 0.2)
    gw = remote_gateway(d.url)
    c = client(gw)
    assert c.ask(INVERTER, read_holding(0, 1)) == reply(0, 1)
    assert c.ask(INVERTER, read_holding(LATE_REGISTER, 2)) == b"\x83\x0b"
    assert c.ask(INVERTER, read_holding(7, 2)) == reply(7, 2)      # never the late one
    for n in range(3):
        assert c.ask(INVERTER, read_holding(n, 1)) == reply(n, 1)
    s = wait_for(gw, lambda s: counter(s, "stray_replies") == 1, "the late reply counted")
    assert counter(s, "timeouts") == 1
    assert (d.connections, d.resets) == (1, 0)


def test_a_lent_client_that_closes_is_forgotten(remote_gateway, client, device):
    d = device(delays=(0.001, 0.002))
    gw = remote_gateway(d.url)
    first = client(gw)
    assert first.ask(INVERTER, read_holding(0, 1)) == reply(0, 1)
    assert first.ask(INVERTER, read_holding(1, 1)) == reply(1, 1)
    first.close()
    wait_for(gw, lambda s: not s["clients"], "the closed client gone")
    with ModbusTcpClient("127.0.0.1", port=gw.port, timeout=5, retries=0) as tcp:
        for n in range(3):
            got = tcp.read_holding_registers(n, count=2, device_id=INVERTER)
            assert got.registers == [100 + n, 101 + n]
    assert (d.connections, d.resets) == (1, 0)


def test_the_units_offset_is_the_lines(tmp_path, remote_gateway, client, device):
    """A route with an offset: the lent request reaches the device at its address there,
    the reply carries the client's own unit."""
    d = device(delays=(0.001, 0.002))
    gw = remote_gateway(d.url)
    path = tmp_path / "mbgw.toml"
    reload(gw, path, 'units = "40-49"\nline = "inverter"',
           'units = "40-49"\nline = "inverter"\noffset = 10')
    c = client(gw)
    for n in range(3):
        assert c.ask(INVERTER, read_holding(n, 1)) == reply(n, 1)
    assert [unit for unit, _ in d.requests] == [INVERTER + 10] * 3
    c.send(struct.pack(">HHHB", 99, 0, 6, INVERTER) + read_holding(5, 1))
    assert c.recv() == (99, INVERTER, reply(5, 1))


@pytest.mark.serial
def test_eight_lent_clients_at_once_each_get_their_own_replies(remote_gateway, device):
    """Eight pymodbus clients, each one request at a time: all lent, their requests taken
    in turn from their sockets, each reply its own."""
    d = device(delays=(0.001, 0.004))
    gw = remote_gateway(d.url, "--max-connections", "16", "--max-connections-per-ip", "16")
    wrong: list = []
    errors: list = []
    threads = [threading.Thread(target=pymodbus_reads, args=(gw.port, 100 * k, 25, wrong, errors))
               for k in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors, (errors, gw.log())
    assert wrong == []
    assert len(d.requests) == 8 * 25
    assert (d.connections, d.resets) == (1, 0)
    s = wait_for(gw, lambda s: counter(s, "replies") == s["counters"]["replies"] == 8 * 25,
                 "the line's and the face's books of every reply")
    assert s["counters"]["requests"] == 8 * 25
