"""Loads the published test vectors in tests/vectors/.  Every line there names its source;
a line without one is an error, so no unsourced value can slip in."""
from dataclasses import dataclass
from pathlib import Path

VECTORS = Path(__file__).resolve().parent.parent / "vectors"


def _rows(name: str, fields: int):
    path = VECTORS / name
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = [part.strip() for part in line.split("|")]
        if len(parts) != fields or not parts[-1]:
            raise ValueError(f"{path}:{number}: expected {fields} fields separated by '|', "
                             f"the last one naming the source")
        yield f"{name}:{number}", parts


@dataclass(frozen=True)
class CheckVector:
    where: str
    frame: bytes        # address .. data
    crc_wire: bytes     # as sent: low byte first
    lrc: int | None
    source: str


@dataclass(frozen=True)
class PduPair:
    label: str
    request: bytes
    response: bytes
    source: str


def check_vectors() -> list[CheckVector]:
    return [CheckVector(where, bytes.fromhex(frame), bytes.fromhex(crc),
                        None if lrc == "-" else int(lrc, 16), source)
            for where, (frame, crc, lrc, source) in _rows("crc16.txt", 4)]


def pdu_pairs() -> list[PduPair]:
    return [PduPair(label, bytes.fromhex(request), bytes.fromhex(response), source)
            for _, (label, request, response, source) in _rows("pdu_pairs.txt", 4)]


CHECK_VECTORS = check_vectors()
PDU_PAIRS = pdu_pairs()
