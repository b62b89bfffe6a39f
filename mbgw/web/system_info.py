"""What the Administration page says of the machine: host name, the serial ports found
(with their /dev/serial/by-id names: the name that stays when a USB adapter moves), the
configuration file's path and checksum."""
import hashlib
import os
import socket
from pathlib import Path

TTY_CLASS = Path("/sys/class/tty")
BY_ID = Path("/dev/serial/by-id")


def serial_ports() -> list[dict]:
    """[{"device": "/dev/ttyUSB0", "by_id": ["usb-FTDI_..."]}]: the ttys backed by a device
    (a UART, a USB adapter), not the virtual consoles."""
    names: dict[str, list[str]] = {}
    try:
        for link in sorted(BY_ID.iterdir()):
            names.setdefault(os.path.realpath(link), []).append(link.name)
    except OSError:
        pass
    ports = []
    try:
        ttys = sorted(TTY_CLASS.iterdir())
    except OSError:
        ttys = []
    for tty in ttys:
        if (tty / "device").exists():
            device = f"/dev/{tty.name}"
            ports.append({"device": device, "by_id": names.get(device, [])})
    return ports


def file_facts(path: Path) -> dict:
    """{"path", "sha256", "size", "modified"}; sha256 None when it cannot be read."""
    try:
        data = path.read_bytes()
        modified: float | None = path.stat().st_mtime
    except OSError:
        return {"path": str(path), "sha256": None, "size": None, "modified": None}
    return {"path": str(path), "sha256": hashlib.sha256(data).hexdigest(), "size": len(data),
            "modified": modified}


def host_name() -> str:
    return socket.gethostname()
