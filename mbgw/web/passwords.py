"""The console's passwords as the configuration file keeps them: scrypt$N$r$p$salt$hash
(salt and hash in base64), checked in constant time."""
import base64
import hashlib
import hmac
import os

from mbgw.errors import ConfigError

SCHEME = "scrypt"
N, R, P = 2 ** 14, 8, 1            # 16 MiB, ~50 ms: a login costs time, a guess costs more
SALT_BYTES = 16
HASH_BYTES = 32
MIN_LENGTH = 10


def hash_password(password: str) -> str:
    if len(password) < MIN_LENGTH:
        raise ConfigError(f"password too short: at least {MIN_LENGTH} characters")
    salt = os.urandom(SALT_BYTES)
    digest = _scrypt(password, salt, N, R, P)
    return "$".join([SCHEME, str(N), str(R), str(P), _b64(salt), _b64(digest)])


def check_hash(text: str, label: str) -> str:
    """The stored form, or ConfigError naming the key: a hand-edited value is refused at
    start rather than at the first login."""
    try:
        _parse(text)
    except (ValueError, TypeError):
        raise ConfigError(f"{label}: not a password hash (scrypt$N$r$p$salt$hash); set it with "
                          f"mbgw config password") from None
    return text


def verify(password: str, stored: str) -> bool:
    n, r, p, salt, digest = _parse(stored)
    return hmac.compare_digest(_scrypt(password, salt, n, r, p), digest)


def _parse(text: str) -> tuple[int, int, int, bytes, bytes]:
    scheme, n, r, p, salt, digest = text.split("$")
    if scheme != SCHEME:
        raise ValueError(scheme)
    numbers = int(n), int(r), int(p)
    if numbers[0] < 2 or numbers[0] & (numbers[0] - 1) or min(numbers) < 1:
        raise ValueError(n)
    return (*numbers, base64.b64decode(salt, validate=True),
            base64.b64decode(digest, validate=True))


def _scrypt(password: str, salt: bytes, n: int, r: int, p: int) -> bytes:
    return hashlib.scrypt(password.encode(), salt=salt, n=n, r=r, p=p,
                          maxmem=256 * 1024 * 1024, dklen=HASH_BYTES)


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode()
