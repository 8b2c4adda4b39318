"""An optional live view of the store's topics in Foxglove, over the Foxglove WebSocket protocol.

A Foxglove WebSocket server (foxglove-sdk) publishing the topics while the host runs, off by
default. Nothing starts unless a `LiveView` is constructed; then `store.add_tap(view.publish)`
shows every topic live (open `view.url` in Foxglove as a "Foxglove WebSocket" connection).

Messages and schemas are exactly those of the MCAP recorder (`log_schema.encode_object`,
`log_schema.schema_bytes`: one encoder), so a layout made on a recording works live and vice versa.
`publish_message` adds messages of Foxglove's own schemas (the urban host's 3D scene,
`host.modules.scene_view`) on the SDK's typed channels.
Times are the objects' `t_s` in ns (simulated time in SIL). The server runs on its own foxglove
Context, so several views (or tests) do not share channels, and is bound to loopback by default:
the protocol has no authentication.
"""

from __future__ import annotations

import threading
from typing import Any

import can
import foxglove
import foxglove.channels
from foxglove import Channel, Context, Schema

from bywire.host.runtime.can_frame import CAN_TOPIC_PREFIX, CanFrame
from bywire.host.runtime.log_schema import (
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    LogError,
    encode_object,
    object_time_ns,
    schema_bytes,
    schema_name_of,
    time_ns,
)


def foxglove_channel(topic: str, msg: Any, context: Context) -> Any:
    """The SDK's typed channel on `topic` for a message of Foxglove's own schemas (`SceneUpdate` ->
    `SceneUpdateChannel`), in `context`: the live view's and `bywire log scene`'s."""
    typed = getattr(foxglove.channels, type(msg).__name__ + "Channel", None)
    if typed is None:
        raise LogError(topic, f"topic {topic!r}: {type(msg).__name__} is no Foxglove schema")
    return typed(topic, context=context)


class LiveView:
    """A Foxglove WebSocket server publishing store objects (`publish`, a store tap) and CAN frames."""

    def __init__(self, port: int, host: str = "127.0.0.1", *, name: str = "bywire") -> None:
        self._context = Context()
        self._lock = threading.Lock()
        self._channels: dict[str, tuple[Channel, type]] = {}
        self._closed = False
        try:
            self._server = foxglove.start_server(name=name, host=host, port=port, context=self._context)
        except Exception as exc:  # the SDK's own error types: a port in use, a bad address
            raise OSError(f"live view: cannot serve on {host}:{port}: {exc}") from exc
        self.host = host
        self.port = self._server.port

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def publish(self, topic: str, obj: object) -> None:
        """Publish a dataclass instance with a `t_s` on `topic` (after close: ignored)."""
        self._publish(topic, obj, object_time_ns(obj, self.url, topic))

    def publish_frame(self, bus: str, msg: can.Message, t_s: float | None = None) -> None:
        """Publish a CAN frame on `/can/<bus>` as the recorder records it."""
        frame = CanFrame.from_message(msg, t_s)
        self._publish(CAN_TOPIC_PREFIX + bus, frame, time_ns(frame.timestamp))

    def publish_message(self, topic: str, msg: Any, log_time_ns: int) -> None:
        """Publish a message of Foxglove's own schemas (`foxglove.messages.SceneUpdate`, `PointCloud`,
        `FrameTransform`, ...) on `topic`, on the SDK's typed channel for its type (a 3D scene)."""
        with self._lock:
            if self._closed:
                return
            known = self._channels.get(topic)
            if known is None:
                try:
                    known = (foxglove_channel(topic, msg, self._context), type(msg))
                except LogError as exc:
                    raise LogError(self.url, exc.problem) from None
                self._channels[topic] = known
            elif known[1] is not type(msg):
                raise LogError(
                    self.url, f"topic {topic!r} carries {known[1].__name__}, not {type(msg).__name__}"
                )
            channel = known[0]
        channel.log(msg, log_time=log_time_ns)

    def _publish(self, topic: str, obj: object, log_time_ns: int) -> None:
        try:
            payload = encode_object(obj)
        except LogError as exc:
            raise LogError(self.url, f"topic {topic!r}: {exc.problem}") from None
        with self._lock:
            # A live view is a convenience: publishing into a closed one (shutdown order) is not an error.
            if self._closed:
                return
            channel = self._channel(topic, type(obj))
        channel.log(payload, log_time=log_time_ns)

    def _channel(self, topic: str, cls: type) -> Channel:
        known = self._channels.get(topic)
        if known is not None:
            if known[1] is not cls:
                raise LogError(self.url, f"topic {topic!r} carries {known[1].__name__}, not {cls.__name__}")
            return known[0]
        schema = Schema(name=schema_name_of(cls), encoding=SCHEMA_ENCODING, data=schema_bytes(cls))
        channel = Channel(topic, schema=schema, message_encoding=MESSAGE_ENCODING, context=self._context)
        self._channels[topic] = (channel, cls)
        return channel

    def topics(self) -> dict[str, Any]:
        """Topic -> the foxglove Schema advertised for it."""
        with self._lock:
            return {topic: channel.schema() for topic, (channel, _) in self._channels.items()}

    def close(self) -> None:
        """Stop the server and close the channels (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            channels = [channel for channel, _ in self._channels.values()]
        for channel in channels:
            channel.close()
        self._server.stop()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
