"""The serial-to-serial bridge (issue 24): a serial master on line panel (master mode) reads a
meter on line serial (slave mode) through mbgw while Modbus TCP clients read the same meter.

Peers that are not ours, on socat pty pairs: the meter is pymodbus's RTU slave, recording every
request it decodes and every reply just before it writes it, with their times; the serial
master is pymodbus's serial client.  Each master reads its own registers (the serial master
0..49, each TCP client a range of its own above), so a reply delivered to the wrong master
shows in its values.  On the meter's line no two frames overlap: requests and replies
alternate, and every request arrives at least t3.5 after the previous reply was written (the
reply's row is taken before its write and the request's after its decoding, so the figure can
only read long, never short)."""
import struct
import threading
import time
from itertools import pairwise
from pathlib import Path

import pytest
from pymodbus.client import ModbusSerialClient

from tests.harness import PtyPair
from tests.integration.lines.test_lines import hr_reply
from tests.modbus import Client, read_holding

pytestmark = pytest.mark.integration

BAUD = 19200
T35_S = 0.001823          # the gateway's t3.5 at 19200 8N1: ceil(3.5 x 10 bits / 19200)
METER = 1
ROUNDS = 40               # reads by each master
TCP_CLIENTS = 2
RUN_S = 60                # the deadline for every master's reads


def wire_rows(record: Path) -> list[tuple[float, str, bytes]]:
    """(time, "rx" | "tx", address + PDU) of each frame the meter decoded or wrote."""
    rows = []
    for row in record.read_text().splitlines():
        when, direction, frame = row.split()
        rows.append((float(when), direction, bytes.fromhex(frame)))
    return rows


@pytest.fixture
def meter(tmp_path, start_peer):
    """Line serial's pty pair, the recording meter (address 1) on its device end."""
    directory = tmp_path / "serial"
    directory.mkdir()
    pair = PtyPair(directory)
    record = directory / "record.txt"
    start_peer("pymodbus_slave.py", pair.device, str(METER), "--silent-unknown",
               "--record", str(record), "--record-replies")
    yield pair, record
    pair.stop()


def serial_master(device: str, done: list, errors: list) -> None:
    """ROUNDS reads through line panel, each of other registers among 0..49."""
    master = ModbusSerialClient(device, baudrate=BAUD, timeout=3, retries=0)
    try:
        assert master.connect()
        for i in range(ROUNDS):
            start, count = i % 40, 1 + i % 10
            reply = master.read_holding_registers(start, count=count, device_id=METER)
            assert not reply.isError(), (i, reply)
            assert reply.registers == [100 + start + n for n in range(count)], (i, reply)
            done.append(("serial", start, count))
    except BaseException as err:
        errors.append(err)
    finally:
        master.close()


def tcp_master(port: int, which: int, done: list, errors: list) -> None:
    """ROUNDS reads of registers among 50+25*which..+24 (each client its own), unit 1."""
    c = Client(port, timeout=3)
    try:
        for i in range(ROUNDS):
            start, count = 50 + 25 * which + i % 15, 1 + i % 10
            tid = i + 1
            c.send(struct.pack(">HHHB", tid, 0, 6, METER) + read_holding(start, count))
            assert c.recv() == (tid, METER, hr_reply(start, count)), (which, i)
            done.append((f"tcp {which}", start, count))
    except BaseException as err:
        errors.append(err)
    finally:
        c.close()


@pytest.mark.serial
def test_a_serial_master_and_tcp_clients_share_a_meter_on_another_line(
        tmp_path, meter, second_pty, start_gateway):
    panel = second_pty      # line panel: mbgw on one end, the serial master on the other
    line, record = meter
    config = tmp_path / "mbgw.toml"
    config.write_text("\n".join([
        "[[line]]", 'name = "panel"', f'device = "{panel.gateway}"', f"baudrate = {BAUD}",
        'mode = "master"',
        "[[route]]", 'from = "panel"', f'units = "{METER}"', 'line = "serial"']) + "\n")
    gw = start_gateway(line.gateway, "--config", str(config), "--baudrate", str(BAUD),
                       "--stout", "500")
    done: list = []
    errors: list = []
    threads = [threading.Thread(target=serial_master, args=(panel.device, done, errors))]
    threads += [threading.Thread(target=tcp_master, args=(gw.port, k, done, errors))
                for k in range(TCP_CLIENTS)]
    for t in threads:
        t.start()
    deadline = time.monotonic() + RUN_S
    for t in threads:
        t.join(max(0.0, deadline - time.monotonic()))
    assert not any(t.is_alive() for t in threads), "the masters did not finish in time"
    assert not errors, errors
    masters = ["serial"] + [f"tcp {k}" for k in range(TCP_CLIENTS)]
    assert {m: sum(1 for d in done if d[0] == m) for m in masters} == dict.fromkeys(
        masters, ROUNDS)

    rows = wire_rows(record)
    # every request, and only those, reached the meter, each once, with the serial master's
    # address rewritten to nothing else than the meter's
    requests = [frame for _, direction, frame in rows if direction == "rx"]
    asked = sorted(bytes((METER,)) + read_holding(start, count) for _, start, count in done)
    assert sorted(requests) == asked
    # no two frames overlap: request, reply, request, reply ...
    assert [direction for _, direction, _ in rows] == ["rx", "tx"] * len(requests)
    for (_, _, request), (_, _, reply) in zip(rows[::2], rows[1::2], strict=True):
        start, count = struct.unpack(">HH", request[2:6])
        assert reply == bytes((METER,)) + hr_reply(start, count)
    # t3.5 of silence from each reply's end to the next request
    gaps = [rows[i + 1][0] - rows[i][0] for i in range(1, len(rows) - 1, 2)]
    assert min(gaps) >= T35_S, f"a request {min(gaps) * 1e6:.0f} us after a reply"
    # The masters took turns: the serial face is one source of the line's round robin, so
    # between two of its requests the line carries one of each TCP client's, and one more
    # when a request of theirs was on the line as its came; the serial master's own
    # turn-around (pymodbus's client, the panel line's framing) may let one more round
    # pass.  A face left behind would show a run of tens.
    serial_at = [i for i, frame in enumerate(requests)
                 if struct.unpack(">H", frame[2:4])[0] < 50]
    assert len(serial_at) == ROUNDS
    between = [b - a - 1 for a, b in pairwise(serial_at)]
    assert max(between) <= 2 * TCP_CLIENTS + 1, between
