"""The exception tree.  Each kind of failure has its own class; nothing raises a base class."""


class MbgwError(Exception):
    """Base of every mbgw error."""


class ConfigError(MbgwError, ValueError):
    """A configuration value is invalid; the message names the option and the reason."""


class SerialError(MbgwError, OSError):
    """The serial device cannot be opened or has gone away."""


class LineTimeout(MbgwError):
    """No valid reply arrived on the serial line before the deadline."""


class ChecksumError(MbgwError):
    """A frame arrived with a bad CRC."""


class FrameError(MbgwError):
    """A frame is malformed (too long, truncated)."""


class ConfigFileError(ConfigError):
    """The configuration file cannot be read or holds unknown keys or bad values.  Each entry of
    `problems` names the key (`net.authip[2]`) and the reason; str() prefixes them with the file."""

    def __init__(self, path, problems) -> None:
        self.path = str(path)
        self.problems = list(problems)
        super().__init__("\n".join(f"{self.path}: {p}" for p in self.problems))


class GatewayTimeout(MbgwError):
    """Master mode: no reply from the remote server within tcpto (connecting included)."""


class NoRoute(MbgwError):
    """Master mode: the remote server cannot be reached (connection refused, no route)."""


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
