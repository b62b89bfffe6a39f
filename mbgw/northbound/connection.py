"""One MQTT session to the broker (MQTT 3.1.1): a new paho client for each CONNECT, so its
Will is that CONNECT's; paho's network loop runs in paho's own thread, and every callback is
handed to the asyncio loop.  Works with paho-mqtt 1.6 (Debian 12) and 2.x: the callback API
version is given only where paho has one."""
import asyncio
import logging
import ssl
from collections.abc import Callable

import paho.mqtt.client as paho

from mbgw.config.mqtt import broker_address

log = logging.getLogger("mbgw.northbound")

CONNECT_TIMEOUT_S = 10.0
KEEPALIVE_S = 30
# publishes paho has not written to the socket yet: beyond this the broker is too slow, and
# a change waits in the latest-value map (counted as dropped when a newer one replaces it)
MAX_UNWRITTEN = 1000


def _client(client_id: str) -> paho.Client:
    kwargs: dict = {"client_id": client_id, "clean_session": True,
                    "protocol": paho.MQTTv311, "reconnect_on_failure": False}
    version = getattr(paho, "CallbackAPIVersion", None)
    if version is not None:                    # paho 2.x; 1.6 has the first API only
        kwargs["callback_api_version"] = version.VERSION2
    return paho.Client(**kwargs)


class Session:
    """A connected client, or one trying to be.  on_message(topic, payload) and on_lost()
    run on the loop."""

    def __init__(self, broker: str, client_id: str, context: ssl.SSLContext | None,
                 loop: asyncio.AbstractEventLoop,
                 on_message: Callable[[str, bytes], None], on_lost: Callable[[], None]) -> None:
        _, self.host, self.port = broker_address(broker)
        self.loop = loop
        self.client = _client(client_id)
        if context is not None:
            self.client.tls_set_context(context)
        self._on_message = on_message
        self._on_lost = on_lost
        self._connack: asyncio.Future = loop.create_future()
        self.queued = 0            # publishes handed to paho (the loop counts)
        self.written = 0           # ... and written to the socket (paho's thread counts)
        self.closing = False
        self.client.on_connect = self._connected
        self.client.on_disconnect = self._disconnected
        self.client.on_message = self._message
        self.client.on_publish = self._published

    def will(self, topic: str, payload: bytes | str, qos: int, retain: bool) -> None:
        self.client.will_set(topic, payload, qos=qos, retain=retain)

    async def open(self) -> str | None:
        """CONNECT and wait for the CONNACK: None when the broker accepted, else why not."""
        try:
            await asyncio.to_thread(self.client.connect, self.host, self.port, KEEPALIVE_S)
        except (OSError, ssl.SSLError, ValueError) as err:
            return str(err) or type(err).__name__
        self.client.loop_start()
        try:
            code = await asyncio.wait_for(self._connack, CONNECT_TIMEOUT_S)
        except TimeoutError:
            return "no CONNACK"
        return None if code == 0 else f"refused ({code})"

    def publish(self, topic: str, payload: bytes | str, qos: int = 0,
                retain: bool = False) -> bool:
        """False (nothing sent) when paho has MAX_UNWRITTEN publishes not yet written."""
        if self.queued - self.written >= MAX_UNWRITTEN:
            return False
        self.queued += 1
        self.client.publish(topic, payload, qos=qos, retain=retain)
        return True

    def subscribe(self, topic: str, qos: int = 0) -> None:
        self.client.subscribe(topic, qos)

    async def close(self) -> None:
        """DISCONNECT (the Will is not sent) and stop paho's thread."""
        self.closing = True
        self.client.disconnect()
        await asyncio.to_thread(self.client.loop_stop)

    # paho's thread: (client, userdata, flags, rc) in API 1, + properties in API 2
    def _connected(self, client, userdata, flags, code, *rest) -> None:
        value = getattr(code, "value", code)
        self.loop.call_soon_threadsafe(self._set_connack, value)

    def _set_connack(self, value: int) -> None:
        if not self._connack.done():
            self._connack.set_result(value)

    def _disconnected(self, client, userdata, *rest) -> None:
        if not self.closing:
            self.loop.call_soon_threadsafe(self._on_lost)

    def _message(self, client, userdata, message) -> None:
        self.loop.call_soon_threadsafe(self._on_message, message.topic, bytes(message.payload))

    def _published(self, client, userdata, mid, *rest) -> None:
        self.written += 1
