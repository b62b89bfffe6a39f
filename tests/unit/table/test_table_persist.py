"""Persistence of the outputs and the free zone (mbgw.table.persist) against mbgw.toml(5),
PERSISTENCE: the file's bytes, the round trip, what survives a restart, damaged files kept
aside for the previous copy, a failing write logged once and retried."""
import logging
import struct
import zlib

import pytest

from mbgw.errors import ConfigError
from mbgw.table.memory import Table
from mbgw.table.persist import Persistence

KEPT = 0x8000 - 0x0800          # registers 0x0800-0x7FFF


@pytest.fixture
def path(tmp_path):
    return tmp_path / "table.bin"


def filled(pairs) -> Table:
    table = Table()
    for address, values in pairs:
        table.write(address, values)
    return table


def restarted(path, interval_s=10) -> tuple[Table, Persistence]:
    table = Table()
    persistence = Persistence(table, path, interval_s)
    persistence.load()
    return table, persistence


def records(caplog, level):
    return [r.getMessage() for r in caplog.records if r.levelno == level]


def test_the_file_is_the_documented_format(path):
    table = filled([(0x0800, [0x1234]), (0x7FFF, [0xABCD]), (0x0000, [0x5555])])
    assert Persistence(table, path, 10).save()
    data = path.read_bytes()
    body = b"MBGWTBL1" + bytes.fromhex("0001 0800 7800") + b"\x12\x34" + \
        bytes(2 * (KEPT - 2)) + b"\xab\xcd"
    assert data == body + struct.pack(">I", zlib.crc32(body))


def test_a_restart_keeps_outputs_and_free_zone_not_inputs(path):
    table = filled([(0x0000, [1, 2]), (0x07FF, [3]), (0x0800, [4, 5]), (0x0FFF, [6]),
                    (0x1000, [7]), (0x7FFE, [8, 9])])
    Persistence(table, path, 10).save()
    table, persistence = restarted(path)
    assert table.read(0x0000, 2) == [0, 0] and table.read(0x07FF) == [0]
    assert table.read(0x0800, 2) == [4, 5] and table.read(0x0FFF) == [6]
    assert table.read(0x1000) == [7] and table.read(0x7FFE, 2) == [8, 9]
    assert not persistence.save()               # loaded: nothing changed since


def test_a_missing_file_is_a_fresh_table_said_at_info(path, caplog):
    caplog.set_level(logging.INFO)
    table, persistence = restarted(path)
    assert table.read(0x0800, 4) == [0] * 4
    assert any(str(path) in m and "does not exist" in m for m in records(caplog, logging.INFO))
    assert not records(caplog, logging.ERROR)
    assert not persistence.save() and not path.exists()   # nothing changed: nothing written


def test_saves_at_most_every_interval_and_only_changes(path):
    table, persistence = restarted(path)
    assert not persistence.maybe_save(100.0)              # nothing changed
    table.write(0x0800, [1])
    assert persistence.maybe_save(100.0)
    table.write(0x0800, [2])
    assert not persistence.maybe_save(109.9)
    assert persistence.maybe_save(110.0)
    assert not persistence.maybe_save(200.0)              # saved, unchanged since
    table.write(0x0000, [9])                              # an input: not kept
    assert not persistence.maybe_save(300.0)
    table.write(0x0800, [3])
    assert persistence.save()                             # at stop: whatever the interval
    assert restarted(path)[0].read(0x0800) == [3]


def test_the_previous_copy_is_kept(path):
    table = Table()
    persistence = Persistence(table, path, 10)
    table.write(0x0800, [1])
    persistence.save()
    table.write(0x0800, [2])
    persistence.save()
    assert restarted(path)[0].read(0x0800) == [2]
    assert restarted(path.with_name("table.bin.prev"))[0].read(0x0800) == [1]
    assert not path.with_name("table.bin.tmp").exists()


def two_saves(path) -> None:
    """A file holding 2 at 0x0800, its previous copy 1."""
    table = Table()
    persistence = Persistence(table, path, 10)
    for value in (1, 2):
        table.write(0x0800, [value])
        persistence.save()


def truncate(data: bytes) -> bytes:
    return data[:-1]


def flip_a_bit(data: bytes) -> bytes:
    damaged = bytearray(data)
    damaged[5000] ^= 0x10
    return bytes(damaged)


def garbage(data: bytes) -> bytes:
    return b"not a table\n" * 100


def other_version(data: bytes) -> bytes:
    body = data[:8] + b"\x00\x02" + data[10:-4]
    return body + struct.pack(">I", zlib.crc32(body))


@pytest.mark.parametrize("damage", [truncate, flip_a_bit, garbage, other_version])
def test_a_damaged_file_is_kept_aside_and_the_previous_copy_used(path, caplog, damage):
    two_saves(path)
    damaged = damage(path.read_bytes())
    path.write_bytes(damaged)
    table, persistence = restarted(path)
    assert table.read(0x0800) == [1]                       # the previous copy's
    errors = records(caplog, logging.ERROR)
    assert len(errors) == 1 and str(path) in errors[0] and "damaged" in errors[0]
    aside = [p for p in path.parent.iterdir() if p.name.startswith("table.bin.damaged-")]
    assert len(aside) == 1 and aside[0].read_bytes() == damaged
    assert aside[0].name in errors[0]
    assert not path.exists()
    # the next save writes the file, and the damaged one never becomes the previous copy
    table.write(0x0800, [3])
    assert persistence.save()
    assert restarted(path)[0].read(0x0800) == [3]
    assert restarted(path.with_name("table.bin.prev"))[0].read(0x0800) == [1]


def test_both_copies_damaged_a_fresh_table(path, caplog):
    two_saves(path)
    prev = path.with_name("table.bin.prev")
    path.write_bytes(garbage(b""))
    prev.write_bytes(truncate(prev.read_bytes()))
    table, persistence = restarted(path)
    assert table.read(0x0800) == [0]
    assert len(records(caplog, logging.ERROR)) == 2
    assert sorted(p.name.split(".damaged-")[0] for p in path.parent.iterdir()) == \
        ["table.bin", "table.bin.prev"]


def test_a_failing_write_is_logged_once_retried_and_never_raised(path, caplog):
    blocker = path.with_name("table.bin.tmp")
    blocker.mkdir()                                        # the temporary file cannot be made
    table = Table()
    persistence = Persistence(table, path, 10)
    table.write(0x0800, [1])
    assert not persistence.maybe_save(0.0)
    table.write(0x0800, [2])
    assert not persistence.maybe_save(10.0)
    assert not persistence.save()
    errors = records(caplog, logging.ERROR)
    assert len(errors) == 1 and str(path) in errors[0]
    blocker.rmdir()
    caplog.set_level(logging.INFO)
    assert persistence.maybe_save(20.0)
    assert any("written again" in m for m in records(caplog, logging.INFO))
    assert restarted(path)[0].read(0x0800) == [2]


def test_the_report_says_what_was_saved_and_while_writes_fail_why(path):
    table = Table()
    persistence = Persistence(table, path, 10)
    assert persistence.report() == {"path": str(path), "interval_s": 10, "last_save": None,
                                    "saves": 0}
    table.write(0x0800, [1])
    assert persistence.save()
    saved = persistence.report()
    assert saved["saves"] == 1 and isinstance(saved["last_save"], float)
    assert "failing" not in saved
    blocker = path.with_name("table.bin.tmp")
    blocker.mkdir()                                        # the temporary file cannot be made
    table.write(0x0800, [2])
    assert not persistence.save()
    failing = persistence.report()
    assert failing["failing"] == f"cannot write {path}: Is a directory"
    assert failing["failing_since"] >= saved["last_save"]
    assert (failing["saves"], failing["last_save"]) == (1, saved["last_save"])
    blocker.rmdir()
    assert persistence.save()
    assert "failing" not in persistence.report() and persistence.report()["saves"] == 2


def test_a_directory_that_is_gone_is_logged_once_and_retried(tmp_path, caplog):
    # (a read-only directory would not stop root, who runs the tests and the service)
    directory = tmp_path / "gone"
    directory.mkdir()
    path = directory / "table.bin"
    table = Table()
    persistence = Persistence(table, path, 10)
    directory.rmdir()
    table.write(0x0800, [1])
    assert not persistence.maybe_save(0.0)
    assert not persistence.maybe_save(10.0)
    assert len(records(caplog, logging.ERROR)) == 1
    directory.mkdir()
    assert persistence.maybe_save(20.0)
    assert restarted(path)[0].read(0x0800) == [1]


def test_a_file_that_cannot_be_read_stops_the_start(path):
    path.mkdir()
    with pytest.raises(ConfigError, match="table-persist .*table.bin: cannot read it"):
        Persistence(Table(), path, 10).load()
    assert path.is_dir()


def test_registers_restored_from_the_file_count_as_written(path):
    table = filled([(0x0800, [0, 7])])
    Persistence(table, path, 10).save()
    restored, _ = restarted(path)
    assert restored.unwritten(0x0800, 0x8000 - 0x0800) is None     # zeros included
    assert restored.unwritten(0, 0x0800) == 0                       # the inputs: not kept
    fresh, _ = restarted(path.with_name("none.bin"))
    assert fresh.unwritten(0x0800, 1) == 0x0800
