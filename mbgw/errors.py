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
