"""Debian's Mosquitto as the tests' MQTT broker, on 127.0.0.1 at a port of its own with its
configuration in a temporary directory; and a subscriber that keeps every message it gets."""
import getpass
import shutil
import socket
import subprocess
import threading
import time
from pathlib import Path

import paho.mqtt.client as paho

from tests.harness import free_port, stop
from tests.wait import until

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
READY_S = 10.0


def _accepts(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
        return True
    except OSError:
        return False


class Broker:
    """mosquitto -c DIR/mosquitto.conf; tls: (certificate, key, CA) to listen with TLS and
    require a client certificate from that CA."""

    def __init__(self, directory: Path, tls: tuple[Path, Path, Path] | None = None) -> None:
        self.dir = directory
        self.port = free_port()
        self.tls = tls
        self.proc: subprocess.Popen | None = None
        self.log_path = directory / f"mosquitto-{self.port}.log"
        # started as root, mosquitto would become user mosquitto, who cannot read the
        # test's directory: it stays the user the tests run as
        lines = [f"user {getpass.getuser()}", f"listener {self.port} 127.0.0.1",
                 "allow_anonymous true",
                 "persistence false", "log_dest stderr", "log_type all"]
        if tls is not None:
            cert, key, ca = tls
            lines += [f"certfile {cert}", f"keyfile {key}", f"cafile {ca}",
                      "require_certificate true"]
        self.config = directory / f"mosquitto-{self.port}.conf"
        self.config.write_text("\n".join(lines) + "\n")
        self.start()

    def start(self) -> None:
        self._log = open(self.log_path, "a")
        self.proc = subprocess.Popen([MOSQUITTO, "-c", str(self.config)], stdout=self._log,
                                     stderr=self._log)
        until(lambda: _accepts(self.port) or self.proc.poll() is not None,
              "mosquitto listening", READY_S)
        assert self.proc.poll() is None, self.log()

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            stop(self.proc)
        self._log.close()

    def log(self) -> str:
        return self.log_path.read_text()

    @property
    def url(self) -> str:
        return f"{'mqtts' if self.tls else 'mqtt'}://127.0.0.1:{self.port}"


class Subscriber:
    """A paho client subscribed to `topics` on the broker, keeping (time, topic, payload,
    retained) of each message, in order."""

    def __init__(self, port: int, *topics: str, client_id: str = "test-subscriber",
                 tls: tuple[Path, Path, Path] | None = None) -> None:
        """tls: (certificate, key, CA) to connect with TLS and a client certificate."""
        kwargs: dict = {"client_id": client_id}
        if hasattr(paho, "CallbackAPIVersion"):
            kwargs["callback_api_version"] = paho.CallbackAPIVersion.VERSION2
        self.client = paho.Client(**kwargs)
        if tls is not None:
            self.client.tls_set(ca_certs=str(tls[2]), certfile=str(tls[0]),
                                keyfile=str(tls[1]))
        self.messages: list[tuple[float, str, bytes, bool]] = []
        self._lock = threading.Lock()
        self._subscribed = threading.Event()
        self.client.on_message = self._message
        self.client.on_subscribe = lambda *args: self._subscribed.set()
        self.client.connect("127.0.0.1", port)
        self.client.loop_start()
        self.client.subscribe([(t, 1) for t in topics])
        assert self._subscribed.wait(READY_S), "never subscribed"

    def _message(self, client, userdata, message) -> None:
        with self._lock:
            self.messages.append((time.monotonic(), message.topic, bytes(message.payload),
                                  bool(message.retain)))

    def received(self, topic_part: str = "") -> list[tuple[float, str, bytes, bool]]:
        with self._lock:
            return [m for m in self.messages if topic_part in m[1]]

    def publish(self, topic: str, payload: bytes | str, retain: bool = False) -> None:
        self.client.publish(topic, payload, qos=1, retain=retain).wait_for_publish(READY_S)

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()
