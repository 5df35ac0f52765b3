"""Zenoh session from the deployment file, typed pub/sub into asyncio, liveliness, queryables.

A :class:`Bus` is one service's view of a shared Zenoh session: every publisher, subscriber,
queryable and liveliness token it declares is closed with it. Subscriptions deliver into asyncio
with an explicit bound: ``latest=True`` keeps only the newest item (frames, poses, odometry),
``queue=N`` keeps the newest N (commands, goals). Nothing builds an unbounded backlog: the
Zenoh thread appends to a bounded deque and schedules at most one wake-up of the event loop.

Every received payload is validated; an invalid one is counted per (key, reason), logged once
per key, and dropped. The service never sees it and keeps running.

Buses sharing a session deliver to each other in-process (``services.local_delivery``): the
message object itself, while Zenoh carries it to everyone else.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import threading
import time
from collections import Counter, deque
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, TypeVar

import cv2
import numpy as np
import zenoh
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from schemas import FrameEncoding, FrameHeader, Keys, Message
from schemas.keys import FRAME
from services.local_delivery import LocalHub, hub_for

log = logging.getLogger("shepherd.bus")

M = TypeVar("M", bound=Message)
T = TypeVar("T")

FRAME_ENCODING = "application/octet-stream;shepherd.Frame/1"
JPEG_ENCODING = "image/jpeg;shepherd.Frame/1"


class ZenohSettings(BaseModel):
    """The ``[zenoh]`` table of a deployment file."""

    model_config = ConfigDict(extra="forbid")
    mode: str = Field(default="peer", pattern="^(peer|client|router)$")
    connect: list[str] = Field(default_factory=list)
    listen: list[str] = Field(default_factory=list)
    multicast_scouting: bool = True
    config_file: Path | None = None
    local_delivery: bool = Field(default=True, description=(
        "services sharing a session take each other's messages in-process (still published "
        "to Zenoh for everyone else)"))


def zenoh_config(settings: ZenohSettings) -> zenoh.Config:
    """Build a ``zenoh.Config``: the native config file first, then our table on top."""
    if settings.config_file is not None:
        if not settings.config_file.is_file():
            raise FileNotFoundError(f"zenoh config_file {settings.config_file} does not exist")
        conf = zenoh.Config.from_file(str(settings.config_file))
    else:
        conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(settings.mode))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(settings.multicast_scouting))
    if settings.connect:
        conf.insert_json5("connect/endpoints", json.dumps(settings.connect))
    if settings.listen:
        conf.insert_json5("listen/endpoints", json.dumps(settings.listen))
    return conf


@contextlib.contextmanager
def open_session(settings: ZenohSettings) -> Iterator[zenoh.Session]:
    """Open a Zenoh session and close it on every path."""
    session = zenoh.open(zenoh_config(settings))
    try:
        yield session
    finally:
        session.close()


@dataclass(frozen=True)
class Frame:
    """A decoded ``camera/frame``: header and image (H x W x 3 uint8 BGR, or H x W mono)."""

    header: FrameHeader
    image: np.ndarray
    received_ns: int


class Rejections:
    """Counts rejected payloads per (key, reason); logs the first rejection of each key."""

    def __init__(self, logger: logging.Logger) -> None:
        self.counts: Counter[tuple[str, str]] = Counter()
        self._logged: set[str] = set()
        self._lock = threading.Lock()
        self._log = logger

    def add(self, key: str, reason: str) -> None:
        with self._lock:
            self.counts[(key, reason)] += 1
            first = key not in self._logged
            self._logged.add(key)
        if first:
            self._log.warning("rejected a payload on %s: %s (further rejections counted)", key,
                              reason)

    def by_key(self) -> dict[str, dict[str, int]]:
        with self._lock:
            out: dict[str, dict[str, int]] = {}
            for (k, reason), n in self.counts.items():
                out.setdefault(k, {})[reason] = n
            return out

    def total(self, key: str | None = None) -> int:
        with self._lock:
            return sum(n for (k, _), n in self.counts.items() if key is None or k == key)


class Subscription(Generic[T]):
    """A bounded mailbox fed from Zenoh's thread and read from asyncio.

    ``maxlen=1`` is the latest-value policy; larger values are a bounded queue that drops the
    oldest item when full. ``dropped`` counts items overwritten before being read.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, maxlen: int) -> None:
        if maxlen < 1:
            raise ValueError("a subscription needs maxlen >= 1")
        self._loop = loop
        self._items: deque[T] = deque(maxlen=maxlen)
        self._lock = threading.Lock()
        self._event = asyncio.Event()
        self._wakeup_pending = False
        self.received = 0
        self.dropped = 0
        self._undeclare: Callable[[], None] = lambda: None
        self._loop_thread = threading.get_ident()  # created in the running loop

    def push(self, item: T) -> None:
        """Called from any thread: store the item and wake the reader (at most one pending)."""
        with self._lock:
            if len(self._items) == self._items.maxlen:
                self.dropped += 1
            self._items.append(item)
            self.received += 1
            schedule = not self._wakeup_pending
            self._wakeup_pending = True
        if schedule:
            if threading.get_ident() == self._loop_thread:  # in-process delivery
                self._wake()
                return
            with contextlib.suppress(RuntimeError):  # loop closed during shutdown
                self._loop.call_soon_threadsafe(self._wake)

    def _wake(self) -> None:
        with self._lock:
            self._wakeup_pending = False
        self._event.set()

    def get_nowait(self) -> T | None:
        """The oldest waiting item, or None."""
        with self._lock:
            item = self._items.popleft() if self._items else None
            if not self._items:
                self._event.clear()
            return item

    def pending(self) -> int:
        with self._lock:
            return len(self._items)

    async def recv(self, timeout: float | None = None) -> T:
        """Wait for the next item; raises TimeoutError after ``timeout`` seconds."""
        while True:
            item = self.get_nowait()
            if item is not None:
                return item
            if timeout is None:
                await self._event.wait()
            else:
                await asyncio.wait_for(self._event.wait(), timeout)

    async def __aiter__(self) -> AsyncIterator[T]:
        while True:
            yield await self.recv()

    def close(self) -> None:
        self._undeclare()


class _FrameSubscription(Subscription[Any]):
    """Holds (header, payload reference, receive time, key); decodes when taken."""

    def __init__(self, loop: asyncio.AbstractEventLoop, maxlen: int, bus: Bus) -> None:
        super().__init__(loop, maxlen)
        self._bus = bus

    def get_nowait(self) -> Frame | None:  # type: ignore[override]
        while (item := super().get_nowait()) is not None:
            header, payload, received_ns, key = item
            data = payload if isinstance(payload, bytes) else payload.to_bytes()
            try:
                return Frame(header, decode_image(header, data), received_ns)
            except ValueError as err:
                self._bus.rejections.add(key, str(err))  # type: ignore[union-attr]
        return None


@dataclass
class Bus:
    """One service's typed view of a shared Zenoh session.

    Args:
        session: an open Zenoh session (owned by the caller).
        keys: the key table for the deployment's namespace.
        service: the service name, used for logs and the ``alive/<service>`` token.
        local_delivery: this bus's subscriptions take messages published by buses of the
            same session straight from them (see ``services.local_delivery``); False takes
            everything from Zenoh. Publishing always serves both kinds of subscriber.
    """

    session: zenoh.Session
    keys: Keys = field(default_factory=Keys)
    service: str = "client"
    rejections: Rejections | None = None  # shared across restarts when the launcher gives one
    local_delivery: bool = True
    _closers: list[Callable[[], None]] = field(default_factory=list, init=False)
    _publishers: dict[str, Any] = field(default_factory=dict, init=False)

    def __post_init__(self) -> None:
        self.log = logging.getLogger(f"shepherd.{self.service}")
        if self.rejections is None:
            self.rejections = Rejections(self.log)
        self._hub: LocalHub = hub_for(self.session)

    # -- lifecycle -------------------------------------------------------------------------

    def close(self) -> None:
        """Undeclare everything this bus declared (not the session itself)."""
        for closer in reversed(self._closers):
            with contextlib.suppress(Exception):
                closer()
        self._closers.clear()
        self._publishers.clear()

    async def __aenter__(self) -> Bus:
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()

    def declare_alive(self) -> None:
        """Declare the liveliness token ``alive/<service>`` until this bus closes."""
        token = self.session.liveliness().declare_token(self.keys.alive(self.service))
        self._closers.append(token.undeclare)

    # -- publishing ------------------------------------------------------------------------

    def _publisher(self, key: str, encoding: str) -> Any:
        pub = self._publishers.get(key)
        if pub is None:
            pub = self.session.declare_publisher(key, encoding=zenoh.Encoding(encoding))
            self._publishers[key] = pub
            self._closers.append(pub.undeclare)
        return pub

    def put(self, suffix: str, message: Message) -> None:
        """Publish a message as JSON on ``<namespace>/<suffix>``."""
        key = self.keys.key(suffix)
        self._hub.deliver(key, message)
        self._publisher(key, message.zenoh_encoding()).put(message.model_dump_json())

    def put_frame(self, header: FrameHeader, payload: bytes | np.ndarray) -> None:
        """Publish a frame: raw pixels (or JPEG bytes), header JSON in the attachment."""
        data = payload.tobytes() if isinstance(payload, np.ndarray) else payload
        expected = header.expected_size()
        if expected is not None and len(data) != expected:
            raise ValueError(f"frame payload is {len(data)} bytes, header says {expected}")
        enc = JPEG_ENCODING if header.encoding is FrameEncoding.JPEG else FRAME_ENCODING
        key = self.keys.key(FRAME)
        self._hub.deliver(key, (header, data))  # bytes: immutable, shared without a copy
        self._publisher(key, enc).put(data, attachment=header.model_dump_json().encode())

    # -- subscribing -----------------------------------------------------------------------

    def _declare(self, key: str, callback: Callable[[zenoh.Sample], None],
                 local: Callable[[str, Any], None] | None = None) -> Callable[[], None]:
        """Subscribe ``callback`` to Zenoh samples and ``local`` to in-process deliveries (then
        Zenoh brings only other sessions' samples); returns the undeclare function."""
        in_process = self.local_delivery and local is not None
        sub = self.session.declare_subscriber(key, callback,
                                              allowed_origin=self._origin(in_process))
        remove = self._hub.add(key, local) if in_process else _nothing  # type: ignore[arg-type]

        def undeclare() -> None:
            remove()
            sub.undeclare()
        self._closers.append(undeclare)
        return undeclare

    @staticmethod
    def _origin(in_process: bool) -> zenoh.Locality:
        """Zenoh samples to take: only other sessions' when this session's come in-process."""
        return zenoh.Locality.REMOTE if in_process else zenoh.Locality.ANY

    def _typed_local(self, model: type[M], push: Callable[[M], None]) -> Callable[[str, Any], None]:
        """An in-process deliverer that pushes ``model`` messages and rejects anything else."""
        def deliver(key: str, item: Any) -> None:
            if isinstance(item, model):
                push(item)
            else:
                got = item.zenoh_encoding() if isinstance(item, Message) else FRAME_ENCODING
                self.rejections.add(  # type: ignore[union-attr]
                    key, f"encoding {got!r}, expected {model.zenoh_encoding()!r}")
        return deliver

    def decode(self, sample: zenoh.Sample, model: type[M]) -> M | None:
        """Validate a JSON sample against ``model``; count and return None when invalid."""
        key = str(sample.key_expr)
        schema = str(sample.encoding)
        if ";shepherd." in schema and schema != model.zenoh_encoding():
            self.rejections.add(key, f"encoding {schema!r}, expected {model.zenoh_encoding()!r}")
            return None
        try:
            return model.model_validate_json(sample.payload.to_bytes())
        except ValidationError as err:
            first = err.errors()[0]
            where = ".".join(str(p) for p in first["loc"]) or "payload"
            self.rejections.add(key, f"invalid {model.__name__}: {where}: {first['msg']}")
        except Exception as err:
            self.rejections.add(key, f"undecodable {model.__name__}: {err}")
        return None

    def subscribe(self, suffix: str, model: type[M], *, latest: bool = True,
                  queue: int = 16, key_expr: str | None = None) -> Subscription[M]:
        """Typed subscription; ``latest=True`` keeps only the newest, else a bounded queue."""
        sub: Subscription[M] = Subscription(asyncio.get_running_loop(), 1 if latest else queue)

        def on_sample(sample: zenoh.Sample) -> None:
            msg = self.decode(sample, model)
            if msg is not None:
                sub.push(msg)

        sub._undeclare = self._declare(key_expr or self.keys.key(suffix), on_sample,
                                       self._typed_local(model, sub.push))
        return sub

    def subscribe_stamped(self, suffix: str, model: type[M], *, queue: int = 256
                          ) -> Subscription[tuple[int, M]]:
        """Bounded queue of (receive time Unix ns, message): for latency measurements."""
        sub: Subscription[tuple[int, M]] = Subscription(asyncio.get_running_loop(), queue)

        def on_sample(sample: zenoh.Sample) -> None:
            msg = self.decode(sample, model)
            if msg is not None:
                sub.push((time.time_ns(), msg))

        sub._undeclare = self._declare(self.keys.key(suffix), on_sample, self._typed_local(
            model, lambda msg: sub.push((time.time_ns(), msg))))
        return sub

    def frame_header(self, sample: zenoh.Sample) -> FrameHeader | None:
        """Validate a ``camera/frame`` sample's header and payload size without copying the
        pixels; count and return None when invalid."""
        key = str(sample.key_expr)
        if sample.attachment is None:
            self.rejections.add(key, "frame without a header attachment")
            return None
        try:
            header = FrameHeader.model_validate_json(sample.attachment.to_bytes())
        except ValidationError as err:
            first = err.errors()[0]
            where = ".".join(str(p) for p in first["loc"]) or "attachment"
            self.rejections.add(key, f"invalid frame header: {where}: {first['msg']}")
            return None
        except Exception as err:
            self.rejections.add(key, f"undecodable frame header: {err}")
            return None
        size = len(sample.payload)
        expected = header.expected_size()
        if size == 0:
            self.rejections.add(key, "empty frame payload")
            return None
        if expected is not None and size != expected:
            self.rejections.add(key, f"frame payload is {size} bytes, header {header.width}x"
                                f"{header.height} {header.encoding.value} needs {expected}")
            return None
        if expected is None:  # JPEG: small enough to check its start and end markers now
            data = sample.payload.to_bytes()
            if data[:2] != b"\xff\xd8" or data[-2:] != b"\xff\xd9":
                self.rejections.add(key, "frame payload is not a decodable JPEG")
                return None
        return header

    def decode_frame(self, sample: zenoh.Sample) -> Frame | None:
        """Decode a ``camera/frame`` sample now; count and return None when invalid."""
        header = self.frame_header(sample)
        if header is None:
            return None
        try:
            image = decode_image(header, sample.payload.to_bytes())
        except ValueError as err:
            self.rejections.add(str(sample.key_expr), str(err))  # type: ignore[union-attr]
            return None
        return Frame(header, image, time.time_ns())

    def subscribe_frames(self, *, latest: bool = True, queue: int = 2) -> Subscription[Frame]:
        """Frames, newest first. Zenoh keeps them in a ring of the policy's size, so under a
        flood stale frames are dropped before they reach Python; a reader thread validates
        each header and size on receipt; pixels are copied and decoded only when taken."""
        size = 1 if latest else queue
        sub = _FrameSubscription(asyncio.get_running_loop(), size, self)
        key = self.keys.key(FRAME)
        zsub = self.session.declare_subscriber(key, zenoh.handlers.RingChannel(size),
                                               allowed_origin=self._origin(self.local_delivery))

        def on_local(key: str, item: Any) -> None:
            if isinstance(item, tuple):  # (header, bytes) from put_frame
                sub.push((item[0], item[1], time.time_ns(), key))
        remove_local = self._hub.add(key, on_local) if self.local_delivery else _nothing
        ring = zsub.handler

        def pump() -> None:
            while True:
                try:
                    sample = ring.recv()
                except zenoh.ZError:  # undeclared: the channel is closed
                    return
                try:
                    header = self.frame_header(sample)
                    if header is not None:
                        sub.push((header, sample.payload, time.time_ns(), str(sample.key_expr)))
                except Exception as err:  # never let one sample stop the frames
                    self.rejections.add(  # type: ignore[union-attr]
                        str(sample.key_expr), f"frame not taken: {type(err).__name__}: {err}")

        threading.Thread(target=pump, name=f"frames-{self.service}", daemon=True).start()
        undeclared = threading.Event()

        def undeclare() -> None:
            if not undeclared.is_set():
                undeclared.set()
                remove_local()
                zsub.undeclare()

        self._closers.append(undeclare)
        sub._undeclare = undeclare
        return sub  # type: ignore[return-value]

    def subscribe_raw(self, key_expr: str, *, queue: int = 256) -> Subscription[zenoh.Sample]:
        """Untyped samples on any key expression (for ``echo`` and recording)."""
        sub: Subscription[zenoh.Sample] = Subscription(asyncio.get_running_loop(), queue)
        sub._undeclare = self._declare(key_expr, sub.push)
        return sub

    # -- queries ---------------------------------------------------------------------------

    def declare_queryable(self, suffix: str, reply: Callable[[], Message | None]) -> None:
        """Answer queries on ``<namespace>/<suffix>`` with ``reply()`` (no answer if None)."""
        key = self.keys.key(suffix)

        def on_query(query: zenoh.Query) -> None:
            try:
                message = reply()
                if message is not None:
                    query.reply(key, message.model_dump_json(),
                                encoding=zenoh.Encoding(message.zenoh_encoding()))
            except Exception as err:
                self.log.warning("queryable %s failed: %s", key, err)
                with contextlib.suppress(Exception):
                    query.reply_err(str(err))

        q = self.session.declare_queryable(key, on_query)
        self._closers.append(q.undeclare)

    async def get(self, suffix: str, model: type[M], timeout: float = 1.0) -> list[M]:
        """Query ``<namespace>/<suffix>`` and return the valid replies."""
        key = self.keys.key(suffix)

        def query() -> list[M]:
            out: list[M] = []
            for reply in self.session.get(key, timeout=timeout):
                if reply.ok is not None:
                    msg = self.decode(reply.ok, model)
                    if msg is not None:
                        out.append(msg)
            return out

        return await asyncio.to_thread(query)


def _nothing() -> None:
    pass


def decode_image(header: FrameHeader, data: bytes) -> np.ndarray:
    """Pixels of a frame payload; raises ValueError naming what does not match the header."""
    if not data:
        raise ValueError("empty frame payload")
    if header.encoding is FrameEncoding.JPEG:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise ValueError("frame payload is not a decodable JPEG")
        if image.shape[:2] != (header.height, header.width):
            raise ValueError(f"JPEG is {image.shape[1]}x{image.shape[0]}, header says "
                             f"{header.width}x{header.height}")
        return image
    expected = header.expected_size()
    if len(data) != expected:
        raise ValueError(f"frame payload is {len(data)} bytes, header {header.width}x"
                         f"{header.height} {header.encoding.value} needs {expected}")
    shape = ((header.height, header.width, 3) if header.encoding is FrameEncoding.BGR8
             else (header.height, header.width))
    return np.frombuffer(data, np.uint8).reshape(shape)


def encode_frame(image: np.ndarray, seq: int, stamp_ns: int, jpeg_quality: int | None = None
                 ) -> tuple[FrameHeader, bytes]:
    """Header and payload for an image (BGR or mono); JPEG when ``jpeg_quality`` is given."""
    height, width = image.shape[:2]
    if jpeg_quality is not None:
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
        if not ok:
            raise ValueError("JPEG encoding failed")
        enc, data = FrameEncoding.JPEG, buf.tobytes()
    else:
        if image.ndim == 3 and image.shape[2] == 1:
            image = image[..., 0]
        enc = FrameEncoding.BGR8 if image.ndim == 3 else FrameEncoding.MONO8
        data = np.ascontiguousarray(image).tobytes()
    return FrameHeader(seq=seq, stamp_ns=stamp_ns, width=width, height=height, encoding=enc), data
