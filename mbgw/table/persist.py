"""The outputs (0x0800-0x0FFF) and the free zone (0x1000-0x7FFF) kept in a file across restarts
(mbgw.toml(5), PERSISTENCE).  The daemons call load() at start, maybe_save(now) from their
periodic tick and save() at stop; no thread of its own.  A write never leaves a half file
(temporary file, fsync, rename, directory fsync), the previous copy stays as PATH.prev, and a
damaged file is renamed aside, never read and never made the previous copy.  The file is
opened without following a link and must be a regular file (fstat), so that a link, a
device or a FIFO swapped in is neither read (it could hang or never end) nor written
through."""
import logging
import os
import stat
import struct
import time
import zlib
from pathlib import Path

from mbgw.errors import ConfigError, Damaged
from mbgw.table.memory import CONFIG_ZONE, OUTPUTS, Table

log = logging.getLogger("mbgw.table")

MAGIC = b"MBGWTBL1"
VERSION = 1
FIRST = OUTPUTS.start
COUNT = CONFIG_ZONE.start - FIRST            # 30,720 registers: outputs and the free zone
HEADER = struct.Struct(">8sHHH")             # magic, version, first register, count
CRC = struct.Struct(">I")
SIZE = HEADER.size + 2 * COUNT + CRC.size


def encode(registers: list[int]) -> bytes:
    body = HEADER.pack(MAGIC, VERSION, FIRST, COUNT) + struct.pack(f">{COUNT}H", *registers)
    return body + CRC.pack(zlib.crc32(body))


def decode(data: bytes) -> list[int]:
    """The registers of a table file; raises Damaged."""
    if len(data) != SIZE:
        raise Damaged(f"{len(data)} bytes, not {SIZE}")
    magic, version, first, count = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise Damaged(f"not an mbgw table file (magic {magic!r})")
    if (version, first, count) != (VERSION, FIRST, COUNT):
        raise Damaged(f"version {version}, registers {first}+{count}: not {VERSION}, "
                      f"{FIRST}+{COUNT}")
    (crc,) = CRC.unpack_from(data, SIZE - CRC.size)
    if zlib.crc32(data[:SIZE - CRC.size]) != crc:
        raise Damaged("bad CRC-32")
    return list(struct.unpack_from(f">{COUNT}H", data, HEADER.size))


def _fsync_dir(directory: Path) -> None:
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


_NO_SURPRISES = os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC


def read_regular(path: Path, limit: int) -> bytes:
    """At most limit bytes of path, a regular file opened without following a link (a FIFO
    would not hang it: non-blocking).  Raises FileNotFoundError, or OSError (ELOOP for a link,
    EINVAL for anything but a regular file)."""
    fd = os.open(path, os.O_RDONLY | _NO_SURPRISES)
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise OSError(22, "not a regular file")
        return os.read(fd, limit)
    finally:
        os.close(fd)


def _write_atomically(path: Path, data: bytes) -> None:
    """path holds data whole, or (on an OSError) is as it was."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.unlink(missing_ok=True)     # whatever was put there: a new file of our own
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NO_SURPRISES, 0o600)
        with os.fdopen(fd, "wb") as out:
            out.write(data)
            out.flush()
            os.fsync(out.fileno())
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


class Persistence:
    """Keeps table's outputs and free zone in path, written at most every interval_s seconds
    when they changed, and at stop."""

    def __init__(self, table: Table, path: str | os.PathLike, interval_s: float) -> None:
        self.table = table
        self.path = Path(path)
        self.prev = self.path.with_name(self.path.name + ".prev")
        self.interval_s = interval_s
        self._saved = -1                          # the generation the file holds; -1 unknown
        self._path_good = False                   # path holds a whole file (may become .prev)
        self._next_at = 0.0                       # monotonic: no save before
        self._failing: str | None = None          # why the last write failed (logged once)
        self._failing_since: float | None = None  # Unix time of the first failure in a row
        self._last_save: float | None = None      # Unix time of the last good write
        self._saves = 0

    # --- start ---

    def load(self) -> bool:
        """Put the file's registers (else PATH.prev's) into the table.  A missing file is a
        fresh table (logged at INFO); a damaged one is renamed aside and logged at ERROR.
        True when registers were loaded.  Raises ConfigError when a file is there but
        cannot be read."""
        registers = self._read(self.path)
        if registers is not None:
            self._path_good = True
        else:
            registers = self._read(self.prev) if self.prev.exists() else None
            if registers is not None:
                log.warning("table: %s read instead of %s", self.prev, self.path)
        if registers is None:
            if not self.path.exists() and not self.prev.exists():
                log.info("table: %s does not exist yet: the outputs and free zone start at 0",
                         self.path)
        else:
            self.table.write(FIRST, registers)
        self._saved = self.table.persist_generation
        return registers is not None

    def _read(self, path: Path) -> list[int] | None:
        try:
            data = read_regular(path, SIZE + 1)
        except FileNotFoundError:
            return None
        except OSError as e:     # not to be written over unread: the gateway does not start
            raise ConfigError(f"table-persist {path}: cannot read it ({e.strerror}; it must "
                              f"be a regular file, not a link)") from None
        try:
            return decode(data)
        except Damaged as e:
            aside = self._put_aside(path)
            log.error("table: %s is damaged (%s): kept as %s", path, e, aside)
            return None

    def _put_aside(self, path: Path) -> Path:
        stamp = time.strftime("%Y%m%dT%H%M%S")
        aside = path.with_name(f"{path.name}.damaged-{stamp}")
        n = 1
        while aside.exists():
            aside = path.with_name(f"{path.name}.damaged-{stamp}.{n}")
            n += 1
        os.rename(path, aside)
        return aside

    # --- running ---

    def maybe_save(self, now: float) -> bool:
        """Save when the registers changed and the interval since the last try has passed
        (now: time.monotonic()).  True when the file was written."""
        if now < self._next_at or self.table.persist_generation == self._saved:
            return False
        self._next_at = now + self.interval_s
        return self.save()

    def save(self) -> bool:
        """Write the registers now if they changed since the file was written (at stop, and
        from maybe_save).  A failure is logged once, until a write succeeds again; never
        raised.  True when the file was written."""
        generation = self.table.persist_generation     # before the copy: never newer than it
        if generation == self._saved:
            return False
        data = encode(self.table.read(FIRST, COUNT))
        try:
            self._keep_previous()
            _write_atomically(self.path, data)
        except OSError as e:
            if self._failing is None:
                log.error("table: cannot write %s (%s): tried again every %g s", self.path,
                          e.strerror or e, self.interval_s)
                self._failing_since = time.time()
            self._failing = f"cannot write {self.path}: {e.strerror or e}"
            return False
        if self._failing is not None:
            log.info("table: %s written again", self.path)
            self._failing = self._failing_since = None
        self._saved = generation
        self._path_good = True
        self._last_save = time.time()
        self._saves += 1
        return True

    def report(self) -> dict:
        """The persistence's part of the status (`mbgw status`, the console): the file, the
        interval, the last good write and, while writes fail, why and since when."""
        report: dict = {"path": str(self.path), "interval_s": self.interval_s,
                        "last_save": self._last_save, "saves": self._saves}
        if self._failing is not None:
            report.update(failing=self._failing, failing_since=self._failing_since)
        return report

    def _keep_previous(self) -> None:
        """The good file becomes PATH.prev (a hard link, so that the file itself is never
        missing); a file not known to be good never does."""
        if not self._path_good:
            return
        link = self.prev.with_name(self.prev.name + ".tmp")
        link.unlink(missing_ok=True)
        try:
            os.link(self.path, link, follow_symlinks=False)
        except FileNotFoundError:
            return
        except OSError:            # a file system without hard links: a copy
            _write_atomically(self.prev, read_regular(self.path, SIZE + 1))
            return
        os.replace(link, self.prev)
