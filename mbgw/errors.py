"""The exception tree.  Each kind of failure has its own class; nothing raises a base class.
A module's own refusals that never leave it (the control socket's BadRequest, the console's
ConfigRefused) derive from MbgwError where they are."""
import os


class MbgwError(Exception):
    """Base of every mbgw error."""


class ConfigError(MbgwError, ValueError):
    """A configuration value is invalid; the message names the option and the reason.  key:
    the option's name when the raiser knows it (the CLI then blames that option)."""

    def __init__(self, *args, key: str | None = None) -> None:
        super().__init__(*args)
        self.key = key


class ListenError(MbgwError, OSError):
    """A port cannot be listened on.  option: the setting that named it (table-port,
    --metrics); port: the port, or the ADDR:PORT of an HTTP endpoint; reason: why, from the
    OSError (errno kept) or as text."""

    def __init__(self, option: str, port: int | str, reason: str | OSError) -> None:
        code = None
        if isinstance(reason, OSError):
            code = reason.errno or None
            reason = os.strerror(reason.errno) if reason.errno else \
                (reason.strerror or str(reason))
        self.option = option
        self.port = port
        self.reason = reason
        super().__init__(code, f"{option} {port}: cannot listen there: {reason}")

    def __str__(self) -> str:
        return str(self.strerror)


class SerialError(MbgwError, OSError):
    """The serial device cannot be opened or has gone away."""


class TargetUnreachable(SerialError):
    """A remote line's device cannot be reached: the connection was refused or timed out, or
    the backoff after such a failure holds the next attempt back."""


class LineTimeout(MbgwError):
    """No valid reply arrived on the serial line before the deadline.  mismatch: the last
    reply PDU that came and did not answer the request (another function, another size),
    for a scenario to tell why it failed; None when none came."""

    def __init__(self, mismatch: bytes | None = None) -> None:
        super().__init__()
        self.mismatch = mismatch


class ChecksumError(MbgwError):
    """A frame arrived with a bad CRC.  address: its first byte (the address, unless noise),
    when the reader says (native.Port.read_request)."""
    address: int | None = None


class FrameError(MbgwError):
    """A frame is malformed (too long, truncated).  address: as ChecksumError's."""
    address: int | None = None


class ConfigFileError(ConfigError):
    """The configuration file cannot be read or holds unknown keys or bad values.  Each entry of
    `problems` names the key (`net.authip[2]`) and the reason; str() prefixes them with the file."""

    def __init__(self, path, problems) -> None:
        self.path = str(path)
        self.problems = list(problems)
        super().__init__("\n".join(f"{self.path}: {p}" for p in self.problems))


class BadHeader(MbgwError, ValueError):
    """An MBAP header (protocol id, length) the stream can no longer be trusted after: the
    connection must close."""


class TableError(MbgwError, ValueError):
    """An access to the table it does not allow (out of range, the configuration zone, a value
    that is not 16 bits); the message names the address and the reason."""


class Damaged(MbgwError, ValueError):
    """A table file that is not a whole one; the message says why."""


class GatewayTimeout(MbgwError):
    """Master mode: no reply from the remote server within tcpto (connecting included)."""


class ConnectTimeout(GatewayTimeout):
    """No connection to the server within the deadline."""


class ConnectionLost(GatewayTimeout):
    """The connection broke while the request was on it (to master mode, no answer)."""


class NoRoute(MbgwError):
    """Master mode: the remote server cannot be reached (connection refused, no route)."""


class HandshakeFailed(NoRoute):
    """The TLS handshake with the server failed: no connection (to master mode, 0x0A)."""


class Interrupted(MbgwError):
    """A line's eventfd was signalled during a wait on a server: the gateway is stopping."""


class BadReply(MbgwError):
    """Master mode: the server's reply (right transaction id) does not answer the request.
    counter: the device's counter for it (wrong_unit, wrong_function, invalid_frames);
    unit, pdu: what the server sent, None when the frame could not be read (a bad header)."""

    def __init__(self, counter: str, reason: str, unit: int | None = None,
                 pdu: bytes | None = None) -> None:
        super().__init__(reason)
        self.counter = counter
        self.unit = unit
        self.pdu = pdu
