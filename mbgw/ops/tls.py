"""Modbus/TCP Security for the Modbus TCP servers: the server's TLS context (TLS 1.2 and 1.3
only, the client's certificate required and checked against the CA), the client context of
the connections to remote servers (`client_context`), the checks of the
certificate files (at start, reload and `mbgw check-config`), and a client's role, read from
its certificate's extension ROLE_OID (a UTF8String) with python3-cryptography."""
import datetime
import os
import ssl

from cryptography import x509
from cryptography.hazmat.primitives.serialization import load_pem_private_key

from mbgw.config.model import ROLE_OID, TlsConfig, UpstreamTlsConfig
from mbgw.errors import ConfigError

_ROLE = x509.ObjectIdentifier(ROLE_OID)
_UTF8STRING = 0x0C


def _read(option: str, path: str) -> bytes:
    try:
        with open(path, "rb") as file:
            return file.read()
    except OSError as err:
        raise ConfigError(f"{option} {path}: cannot be read: {err.strerror}") from None


def check_certificate(path: str, option: str = "tls-cert",
                      now: datetime.datetime | None = None) -> x509.Certificate:
    """The PEM certificate in path, refused when it cannot be read or is not valid now (the
    message names the file and the date).  Raises ConfigError."""
    try:
        cert = x509.load_pem_x509_certificate(_read(option, path))
    except ValueError as err:
        raise ConfigError(f"{option} {path}: not a PEM certificate ({err})") from None
    now = now or datetime.datetime.utcnow()
    if now < cert.not_valid_before:
        raise ConfigError(f"{option} {path}: not valid before {cert.not_valid_before} UTC")
    if now > cert.not_valid_after:
        raise ConfigError(f"{option} {path}: expired on {cert.not_valid_after} UTC")
    return cert


def check_key(path: str, option: str = "tls-key") -> None:
    try:
        load_pem_private_key(_read(option, path), password=None)
    except (ValueError, TypeError) as err:
        raise ConfigError(f"{option} {path}: not an unencrypted PEM private key ({err})") \
            from None


def check_ca(path: str, option: str = "tls-ca") -> None:
    try:
        x509.load_pem_x509_certificate(_read(option, path))
    except ValueError as err:
        raise ConfigError(f"{option} {path}: not a PEM certificate ({err})") from None


def file_stamps(*paths: str | None) -> tuple:
    """(path, mtime_ns, size) of each file: a renewed one compares different."""
    stamps = []
    for path in paths:
        if path is not None:
            try:
                st = os.stat(path)
            except OSError:
                continue            # the checks say why
            stamps.append((path, st.st_mtime_ns, st.st_size))
    return tuple(stamps)


def server_context(cfg: TlsConfig) -> ssl.SSLContext:
    """The context of the TLS listener: the files checked, then loaded.  Raises ConfigError."""
    assert cfg.cert is not None and cfg.key is not None and cfg.ca is not None
    check_certificate(cfg.cert, "tls.cert")
    check_key(cfg.key, "tls.key")
    check_ca(cfg.ca, "tls.ca")
    return _context(ssl.PROTOCOL_TLS_SERVER, ("tls.cert", cfg.cert), ("tls.key", cfg.key),
                    ("tls.ca", cfg.ca))


def client_context(cfg: UpstreamTlsConfig) -> ssl.SSLContext:
    """The context of the connections to remote servers over TLS: TLS 1.2/1.3, the server's
    certificate checked against server-ca (not its name: servers are addressed by IP, as in
    the slaveid ranges), mbgw's client certificate presented.  Raises ConfigError."""
    assert cfg.client_cert is not None and cfg.client_key is not None \
        and cfg.server_ca is not None
    check_certificate(cfg.client_cert, "tls.client-cert")
    check_key(cfg.client_key, "tls.client-key")
    check_ca(cfg.server_ca, "tls.server-ca")
    return _context(ssl.PROTOCOL_TLS_CLIENT, ("tls.client-cert", cfg.client_cert),
                    ("tls.client-key", cfg.client_key), ("tls.server-ca", cfg.server_ca))


def _context(protocol: int, cert: tuple[str, str], key: tuple[str, str],
             ca: tuple[str, str]) -> ssl.SSLContext:
    """TLS 1.2 or 1.3, the peer's certificate required and checked against ca, ours (cert,
    key) shown; each (option, path).  Raises ConfigError naming the option."""
    context = ssl.SSLContext(protocol)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    context.maximum_version = ssl.TLSVersion.TLSv1_3
    if protocol == ssl.PROTOCOL_TLS_CLIENT:
        context.check_hostname = False
    context.verify_mode = ssl.CERT_REQUIRED
    load_pair(context, cert, key)
    try:
        context.load_verify_locations(ca[1])
    except (ssl.SSLError, OSError) as err:
        raise ConfigError(f"{ca[0]} {ca[1]}: cannot be used ({err})") from None
    return context


def load_pair(context: ssl.SSLContext, cert: tuple[str, str], key: tuple[str, str]) -> None:
    """The certificate and its private key into context, each (key label, path).  Raises
    ConfigError naming the key when the key does not go with the certificate."""
    try:
        context.load_cert_chain(cert[1], key[1])
    except (ssl.SSLError, OSError) as err:
        raise ConfigError(f"{key[0]}: {key[1]} does not match {cert[0]} {cert[1]} "
                          f"({getattr(err, 'reason', None) or err})") from None


def check_pair(cert: tuple[str, str], key: tuple[str, str]) -> None:
    """A server certificate and its key (each (key label, path)) as an HTTPS server loads
    them: each readable and well-formed, and going together.  Raises ConfigError."""
    check_certificate(cert[1], cert[0])
    check_key(key[1], key[0])
    load_pair(ssl.create_default_context(ssl.Purpose.CLIENT_AUTH), cert, key)


def handshake_step(sock: ssl.SSLSocket) -> tuple[str, str]:
    """One step of a non-blocking server handshake: ("done", ""), ("read", "") or
    ("write", "") (wait for the socket, then step again), or ("failed", why)."""
    try:
        sock.do_handshake()
    except ssl.SSLWantReadError:
        return "read", ""
    except ssl.SSLWantWriteError:
        return "write", ""
    except ssl.SSLError as err:
        return "failed", f"TLS handshake refused ({err.reason or err})"
    except OSError as err:
        return "failed", f"TLS handshake failed ({err.strerror or err})"
    return "done", ""


def role_of(der: bytes | None) -> str | None:
    """The role in a client certificate (DER), or None when it has none (or not as a
    UTF8String)."""
    if not der:
        return None
    try:
        extension = x509.load_der_x509_certificate(der).extensions.get_extension_for_oid(_ROLE)
    except (x509.ExtensionNotFound, ValueError):
        return None
    value = getattr(extension.value, "value", b"")
    return _utf8_string(value)


def _utf8_string(der: bytes) -> str | None:
    """A DER UTF8String's text, or None."""
    if len(der) < 2 or der[0] != _UTF8STRING:
        return None
    length, start = der[1], 2
    if length & 0x80:
        size = length & 0x7F
        if not 1 <= size <= 2 or len(der) < 2 + size:
            return None
        length, start = int.from_bytes(der[2:2 + size], "big"), 2 + size
    if len(der) != start + length:
        return None
    try:
        return der[start:].decode("utf-8")
    except UnicodeDecodeError:
        return None
