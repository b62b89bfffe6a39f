"""The console's stored passwords (mbgw/web/passwords.py): scrypt$N$r$p$salt$hash checked
against RFC 7914's published scrypt vectors, a new hash's form, and what check_hash refuses
with the key's name."""
import base64
import hashlib

import pytest

from mbgw.errors import ConfigError
from mbgw.web.passwords import MIN_LENGTH, check_hash, hash_password, verify


def b64(data: bytes) -> str:
    return base64.b64encode(data).decode()


# RFC 7914 (The scrypt Password-Based Key Derivation Function), section 12, the 2nd and 3rd
# test vectors (dkLen 64); a stored hash keeps 32 bytes, the first 32 of the derived key
# (PBKDF2's output, cut shorter, is the same bytes).
RFC_7914 = [
    ("password", b"NaCl", 1024, 8, 16, bytes.fromhex(
        "fdbabe1c9d3472007856e7190d01e9fe7c6ad7cbc8237830e77376634b373162"
        "2eaf30d92e22a3886ff109279d9830dac727afb94a83ee6d8360cbdfa2cc0640")),
    ("pleaseletmein", b"SodiumChloride", 16384, 8, 1, bytes.fromhex(
        "7023bdcb3afd7348461c06cd81fd38ebfda8fbba904f8e3ea9b543f6545da1f2"
        "d5432955613f0fcf62d49705242a9af9e61e85dc0d651e40dfcf017b45575887")),
]


@pytest.mark.parametrize("password, salt, n, r, p, key", RFC_7914, ids=["NaCl", "Sodium"])
def test_a_stored_hash_made_from_the_rfc_vector_verifies_its_password_only(
        password, salt, n, r, p, key):
    stored = f"scrypt${n}${r}${p}${b64(salt)}${b64(key[:32])}"
    assert check_hash(stored, "web.admin-password") == stored
    assert verify(password, stored)
    assert not verify(password + "!", stored)
    assert not verify(password, f"scrypt${n}${r}${p}${b64(salt)}${b64(key[32:])}")


def test_a_new_hash_is_scrypt_2_14_8_1_with_its_own_salt():
    password = "correct horse battery"
    first, second = hash_password(password), hash_password(password)
    assert first != second
    for stored in (first, second):
        scheme, n, r, p, salt, key = stored.split("$")
        assert (scheme, n, r, p) == ("scrypt", "16384", "8", "1")
        salt_bytes = base64.b64decode(salt, validate=True)
        assert len(salt_bytes) == 16
        assert base64.b64decode(key, validate=True) == hashlib.scrypt(
            password.encode(), salt=salt_bytes, n=16384, r=8, p=1, dklen=32)
        assert verify(password, stored) and not verify("correct horse battery!", stored)


def test_a_password_shorter_than_the_minimum_is_refused():
    with pytest.raises(ConfigError, match=f"password too short: at least {MIN_LENGTH}"):
        hash_password("x" * (MIN_LENGTH - 1))
    assert hash_password("x" * MIN_LENGTH).startswith("scrypt$")


SALT, KEY = b64(b"s" * 16), b64(b"k" * 32)


@pytest.mark.parametrize("stored", [
    "",
    "plain text password",
    f"bcrypt$16384$8$1${SALT}${KEY}",                 # another scheme
    f"scrypt$16384$8$1${SALT}",                       # a field missing
    f"scrypt$16384$8$1${SALT}${KEY}$",                # one too many
    f"scrypt$1000$8$1${SALT}${KEY}",                  # N not a power of 2
    f"scrypt$1$8$1${SALT}${KEY}",                     # N below 2
    f"scrypt$16384$0$1${SALT}${KEY}",                 # r below 1
    f"scrypt$16384$8$0${SALT}${KEY}",                 # p below 1
    f"scrypt$16384$8$x${SALT}${KEY}",                 # not a number
    f"scrypt$16384$8$1$not*base64${KEY}",             # salt not base64
    f"scrypt$16384$8$1${SALT}$abc",                   # hash not base64 (bad padding)
])
def test_a_hand_edited_hash_is_refused_naming_the_key(stored):
    with pytest.raises(ConfigError, match=r"^web\.user-password: not a password hash "
                                          r"\(scrypt\$N\$r\$p\$salt\$hash\); set it with "
                                          r"mbgw config password$"):
        check_hash(stored, "web.user-password")
