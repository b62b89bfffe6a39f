"""mbgw.line.native.crc16 against published CRC-16/MODBUS values."""
import pytest

from mbgw.line import native
from tests.unit.vectors import CHECK_VECTORS

VECTOR_IDS = [v.where for v in CHECK_VECTORS]


def test_vector_file_is_not_empty():
    assert len(CHECK_VECTORS) >= 10


@pytest.mark.parametrize("vector", CHECK_VECTORS, ids=VECTOR_IDS)
def test_crc_matches_published_value_low_byte_first(vector):
    crc = native.crc16(vector.frame)
    assert crc.to_bytes(2, "little") == vector.crc_wire, vector.source


@pytest.mark.parametrize("vector", CHECK_VECTORS, ids=VECTOR_IDS)
def test_crc_over_frame_and_its_crc_is_zero(vector):
    assert native.crc16(vector.frame + vector.crc_wire) == 0, vector.source


@pytest.mark.parametrize("vector", CHECK_VECTORS, ids=VECTOR_IDS)
def test_crc_detects_a_flipped_bit(vector):
    damaged = bytearray(vector.frame + vector.crc_wire)
    damaged[0] ^= 0x01
    assert native.crc16(bytes(damaged)) != 0


def test_crc_modbus_check_value():
    # CRC RevEng catalogue, CRC-16/MODBUS: check=0x4b37 (over b"123456789").
    assert native.crc16(b"123456789") == 0x4B37


def test_crc_of_nothing_is_the_initial_value():
    # Serial Line V1.02 6.2.2 step 1: the CRC register is preloaded with FFFF hex.
    assert native.crc16(b"") == 0xFFFF
