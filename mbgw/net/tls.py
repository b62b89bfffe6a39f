"""Modbus/TCP Security for the Modbus TCP servers: the server's TLS context (TLS 1.2 and 1.3
only, AEAD suites with ECDHE, the AES-CCM ones of the Secure SunSpec profile included, no
renegotiation, session tickets; the client's certificate required and checked against the
CA and the CRL), the client context of the connections to remote servers (`client_context`)
and the check of a server's certificate against the address dialled or a pinned fingerprint
(`server_mismatch`), the checks of the certificate files (at start, reload and `mbgw
check-config`), and a client's role, read from its certificate's extension ROLE_OID (a
UTF8String) with python3-cryptography, and the server handshake stepped in a poll loop
(ServerHandshake, handshake_step) within the limits every TLS listener keeps."""
from __future__ import annotations

import ctypes
import datetime
import hashlib
import ipaddress
import logging
import os
import socket
import ssl
from collections.abc import Callable
from typing import TYPE_CHECKING

from mbgw.config.model import ROLE_OID, TlsConfig, UpstreamTlsConfig
from mbgw.errors import ConfigError

# python3-cryptography is imported by the functions that read a certificate: loading it is
# a good part of a daemon's start, which one without TLS need not pay.
if TYPE_CHECKING:
    from cryptography import x509

log = logging.getLogger("mbgw.tls")

# TLS handshakes under way at once on one listener, and how long one may take (until the
# daemon sets request-timeout): a flood of connections that never finish (or garbage) costs
# the loop one wake-up each and no more.
MAX_HANDSHAKES = 64
HANDSHAKE_TIMEOUT_S = 10.0

_UTF8STRING = 0x0C
# TLS 1.2: ECDHE key exchange and AEAD only (no RSA key exchange, no CBC); AES-128-CCM(8) for
# the Secure SunSpec Modbus profile's devices (ECDSA, P-256 certificates)
TLS12_CIPHERS = ("ECDHE+AESGCM:ECDHE+CHACHA20:ECDHE-ECDSA-AES128-CCM:ECDHE-ECDSA-AES256-CCM:"
                 "ECDHE-ECDSA-AES128-CCM8:!aNULL")
# towards servers (devices mbgw does not choose): the same first, then what Python offers by
# default besides (CBC with SHA-2, never SHA-1), so an older server still answers
UPSTREAM_TLS12_CIPHERS = TLS12_CIPHERS + ":ECDH+AES:DHE+AES:!aNULL:!eNULL:!aDSS:!SHA1"
# TLS 1.3: OpenSSL's three, and TLS_AES_128_CCM_SHA256 (OpenSSL leaves it out by default)
TLS13_SUITES = ("TLS_AES_256_GCM_SHA384:TLS_CHACHA20_POLY1305_SHA256:TLS_AES_128_GCM_SHA256:"
                "TLS_AES_128_CCM_SHA256")


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
    from cryptography import x509

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
    from cryptography.hazmat.primitives.serialization import load_pem_private_key

    try:
        load_pem_private_key(_read(option, path), password=None)
    except (ValueError, TypeError) as err:
        raise ConfigError(f"{option} {path}: not an unencrypted PEM private key ({err})") \
            from None


def check_ca(path: str, option: str = "tls-ca") -> None:
    from cryptography import x509

    try:
        x509.load_pem_x509_certificate(_read(option, path))
    except ValueError as err:
        raise ConfigError(f"{option} {path}: not a PEM certificate ({err})") from None


def check_crl(path: str, option: str = "tls-crl") -> x509.CertificateRevocationList:
    """The PEM CRL in path.  Raises ConfigError."""
    from cryptography import x509

    try:
        return x509.load_pem_x509_crl(_read(option, path))
    except ValueError as err:
        raise ConfigError(f"{option} {path}: not a PEM certificate revocation list ({err})") \
            from None


def check_crl_issuer(crl_path: str, ca_path: str) -> None:
    """The CRL must be signed by one of the CAs in ca_path (else every client would be
    refused).  Raises ConfigError."""
    from cryptography import x509

    crl = check_crl(crl_path)
    marker = b"-----BEGIN CERTIFICATE-----"
    for pem in _read("tls-ca", ca_path).split(marker)[1:]:
        try:
            ca = x509.load_pem_x509_certificate(marker + pem)
            if crl.is_signature_valid(ca.public_key()):  # type: ignore[arg-type]
                return
        except (ValueError, TypeError):     # check_ca says why; a key CRLs are not signed with
            continue
    raise ConfigError(f"tls-crl {crl_path}: not signed by a CA of tls-ca {ca_path}")


def _crl_expiry(path: str, now: datetime.datetime | None = None) -> None:
    """Log an error when the CRL is past its next update: OpenSSL then refuses every client
    until a fresh one is loaded (SIGHUP)."""
    try:
        crl = check_crl(path)
    except ConfigError:
        return
    now = now or datetime.datetime.utcnow()
    if crl.next_update is not None and now > crl.next_update:
        log.error("tls-crl %s: past its next update (%s UTC): every TLS client is refused "
                  "until a fresh CRL is loaded (systemctl reload mbgw)", path, crl.next_update)


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


def server_context(cfg: TlsConfig, log_expiry: bool = True) -> ssl.SSLContext:
    """The context of the TLS listener: the files checked, then loaded.  Raises ConfigError.
    log_expiry=False: a check only (mbgw.ops.preflight), which leaves the log to the start."""
    assert cfg.cert is not None and cfg.key is not None and cfg.ca is not None
    check_certificate(cfg.cert, "tls.cert")
    check_key(cfg.key, "tls.key")
    check_ca(cfg.ca, "tls.ca")
    context = _context(ssl.PROTOCOL_TLS_SERVER, ("tls.cert", cfg.cert), ("tls.key", cfg.key),
                       ("tls.ca", cfg.ca))
    if cfg.crl is not None:
        check_crl_issuer(cfg.crl, cfg.ca)
        try:
            context.load_verify_locations(cfg.crl)
        except (ssl.SSLError, OSError) as err:
            raise ConfigError(f"tls-crl {cfg.crl}: cannot be used ({err})") from None
        context.verify_flags |= ssl.VERIFY_CRL_CHECK_LEAF
        if log_expiry:
            _crl_expiry(cfg.crl)
    return context


def client_context(cfg: UpstreamTlsConfig) -> ssl.SSLContext:
    """The context of the connections to remote servers over TLS: TLS 1.2/1.3, the server's
    certificate checked against server-ca (its name or pin by the pool after the handshake,
    server_mismatch: OpenSSL's check_hostname would need one context per pin), mbgw's client
    certificate presented.  Raises ConfigError."""
    assert cfg.client_cert is not None and cfg.client_key is not None \
        and cfg.server_ca is not None
    check_certificate(cfg.client_cert, "tls.client-cert")
    check_key(cfg.client_key, "tls.client-key")
    check_ca(cfg.server_ca, "tls.server-ca")
    return _context(ssl.PROTOCOL_TLS_CLIENT, ("tls.client-cert", cfg.client_cert),
                    ("tls.client-key", cfg.client_key), ("tls.server-ca", cfg.server_ca))


def broker_context(cert: str | None, key: str | None, ca: str | None) -> ssl.SSLContext:
    """The context of the connection to an MQTT broker: TLS 1.2/1.3, the broker's
    certificate checked against ca (None: the system's CAs) and against the broker's host
    name; the client certificate (cert, key) shown when given.  Raises ConfigError."""
    context = ssl.create_default_context(ssl.Purpose.SERVER_AUTH, cafile=ca)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    if cert is not None and key is not None:
        check_certificate(cert, "mqtt.cert")
        load_pair(context, ("mqtt.cert", cert), ("mqtt.key", key))
    return context


def _context(protocol: int, cert: tuple[str, str], key: tuple[str, str],
             ca: tuple[str, str]) -> ssl.SSLContext:
    """TLS 1.2 or 1.3, the peer's certificate required and checked against ca, ours (cert,
    key) shown; each (option, path).  Raises ConfigError naming the option."""
    context = ssl.SSLContext(protocol)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    context.maximum_version = ssl.TLSVersion.TLSv1_3
    context.options |= ssl.OP_NO_RENEGOTIATION | ssl.OP_NO_COMPRESSION
    context.set_ciphers(TLS12_CIPHERS if protocol == ssl.PROTOCOL_TLS_SERVER
                        else UPSTREAM_TLS12_CIPHERS)
    _set_tls13_suites(context, TLS13_SUITES)
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


def _set_tls13_suites(context: ssl.SSLContext, suites: str) -> None:
    """SSL_CTX_set_ciphersuites, which Python's ssl does not offer, on the context's SSL_CTX
    (the first field after the object's header in CPython's PySSLContext, checked by reading
    its options back before it is written)."""
    libssl = _libssl()
    pointer = ctypes.c_void_p.from_address(id(context) + object.__basicsize__).value
    if libssl.SSL_CTX_get_options(pointer) != context.options or \
            libssl.SSL_CTX_set_ciphersuites(pointer, suites.encode()) != 1:
        raise ConfigError("TLS: cannot set the TLS 1.3 cipher suites on this Python")


_LIBSSL: list[ctypes.CDLL] = []


def _libssl() -> ctypes.CDLL:
    """libssl as Python's ssl module has loaded it."""
    if not _LIBSSL:
        libssl = ctypes.CDLL(ssl._ssl.__file__)  # type: ignore[attr-defined]
        if not hasattr(libssl, "SSL_CTX_get_options"):  # _ssl not linked to libssl
            libssl = ctypes.CDLL("libssl.so.3")
        libssl.SSL_CTX_get_options.restype = ctypes.c_uint64
        libssl.SSL_CTX_get_options.argtypes = [ctypes.c_void_p]
        libssl.SSL_CTX_set_ciphersuites.restype = ctypes.c_int
        libssl.SSL_CTX_set_ciphersuites.argtypes = [ctypes.c_void_p, ctypes.c_char_p]
        _LIBSSL.append(libssl)
    return _LIBSSL[0]


def server_mismatch(der: bytes | None, host: str, fingerprint: bytes | None) -> str | None:
    """Why a server's certificate (DER, its chain to server-ca checked already) is not the
    one of the server dialled at host, or None when it is: its SHA-256 is fingerprint when
    one is pinned, else host (an IP address or a DNS name) is in its subjectAltName."""
    from cryptography import x509

    if not der:
        return "the server showed no certificate"
    if fingerprint is not None:
        if hashlib.sha256(der).digest() == fingerprint:
            return None
        return "the server's certificate is not the one pinned (fingerprint " \
            f"{hashlib.sha256(der).digest().hex(':').upper()})"
    try:
        names = x509.load_der_x509_certificate(der).extensions.get_extension_for_class(
            x509.SubjectAlternativeName).value
    except (x509.ExtensionNotFound, ValueError):
        return f"the server's certificate has no subjectAltName: it is not for {host}"
    try:
        address = ipaddress.ip_address(host.strip("[]").split("%", 1)[0])
    except ValueError:
        address = None
    if address is not None:
        if address in names.get_values_for_type(x509.IPAddress):
            return None
    elif any(_dns_matches(name, host) for name in names.get_values_for_type(x509.DNSName)):
        return None
    return f"the server's certificate is not for {host}"


def _dns_matches(name: str, host: str) -> bool:
    """RFC 6125: a whole name, or a wildcard for the leftmost label only."""
    name, host = name.lower().rstrip("."), host.lower().rstrip(".")
    if name.startswith("*."):
        first, _, rest = host.partition(".")
        return bool(first) and rest == name[2:]
    return name == host


def first_byte(sock: socket.socket) -> bool | None:
    """Before a server handshake, on the accepted socket: True once the client has sent a
    byte, None while it has not, False when it closed or reset the connection first (a health
    check's connect and close: no handshake refused)."""
    try:
        return bool(sock.recv(1, socket.MSG_PEEK))
    except (BlockingIOError, InterruptedError):
        return None
    except OSError:
        return False


def start_handshake(context: ssl.SSLContext, sock: socket.socket) -> ssl.SSLSocket | str:
    """The accepted socket wrapped for a non-blocking server handshake, or why it cannot be
    (the peer has reset it meanwhile)."""
    try:
        return context.wrap_socket(sock, server_side=True, do_handshake_on_connect=False)
    except OSError as err:          # ssl.SSLError included
        return f"TLS handshake failed ({_why(err)})"


def handshake_step(sock: ssl.SSLSocket,
                   describe: Callable[[OSError], str] | None = None) -> tuple[str, str]:
    """One step of a non-blocking handshake: ("done", ""), ("read", "") or ("write", "")
    (wait for the socket, then step again), or ("failed", why).  why: describe(err), by
    default a server's (refusal(): naming the kind of refusal, the log is rate-limited by
    it)."""
    try:
        sock.do_handshake()
    except ssl.SSLWantReadError:
        return "read", ""
    except ssl.SSLWantWriteError:
        return "write", ""
    except OSError as err:          # ssl.SSLError included
        return "failed", (describe or refusal)(err)
    return "done", ""


class ServerHandshake:
    """A TLS client's handshake on an accepted, non-blocking socket, one step each time the
    socket is ready: `sock` is the plain socket until the client's first byte, then the
    SSLSocket."""
    __slots__ = ("sock", "fd", "address", "context")

    def __init__(self, sock: socket.socket, address, context: ssl.SSLContext) -> None:
        self.sock = sock
        self.fd = sock.fileno()
        self.address = address
        self.context = context

    def step(self) -> tuple[str, str]:
        """("read", "") or ("write", ""): wait for the socket, then step again; ("probe", ""):
        closed or reset before a byte (a health check's connect and close, no handshake
        refused); ("failed", why); ("done", "")."""
        if not isinstance(self.sock, ssl.SSLSocket):
            heard = first_byte(self.sock)
            if heard is None:
                return "read", ""
            if not heard:
                return "probe", ""
            tls = start_handshake(self.context, self.sock)
            if isinstance(tls, str):
                return "failed", tls
            self.sock = tls
        return handshake_step(self.sock)


def refusal(err: OSError) -> str:
    """Why a server's handshake with a client failed."""
    if isinstance(err, ssl.SSLCertVerificationError):
        return f"TLS handshake refused (client certificate: {err.verify_message})"
    if isinstance(err, ssl.SSLError):
        return f"TLS handshake refused ({_why(err)})"
    return f"TLS handshake failed ({_why(err)})"


def _why(err: OSError) -> str:
    if isinstance(err, ssl.SSLError):
        return err.reason or str(err.args[1] if len(err.args) > 1 else err)
    return err.strerror or str(err)


def role_of(der: bytes | None) -> str | None:
    """The role in a client certificate (DER), or None when it has none (or not as a
    UTF8String)."""
    from cryptography import x509

    if not der:
        return None
    try:
        extension = x509.load_der_x509_certificate(der).extensions.get_extension_for_oid(
            x509.ObjectIdentifier(ROLE_OID))
    except (x509.ExtensionNotFound, ValueError):
        return None
    value = getattr(extension.value, "value", b"")
    return _utf8_string(value) or None       # an empty role is none


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
