"""A service's typed view of the shared Zenoh session: pub/sub into asyncio, queries, tokens.

A :class:`Bus` closes every publisher, subscriber, queryable and liveliness token it declared
when it closes. Subscriptions deliver into bounded mailboxes (``services.runtime.mailbox``):
``latest=True`` keeps only the newest item (frames, poses, odometry), ``queue=N`` the newest N
(commands, goals).

Every received payload is validated; an invalid one is counted per (key, reason), logged once
per key, and dropped. The service never sees it and keeps running. JSON payloads larger than
``limits.max_json_bytes`` are refused before parsing; frames are checked before decoding
(``services.runtime.frames``) and JPEGs decoded on the frame thread, off the event loop.

Buses sharing a session deliver to each other in-process (``services.runtime.local_delivery``):
the message object itself, while Zenoh carries it to everyone else.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
import zenoh
import zenoh.ext
from pydantic import ValidationError

from schemas import FrameEncoding, FrameHeader, Keys, Message, describe_validation_error
from schemas.keys import FRAME
from services.runtime.frames import (
    FRAME_ENCODING,
    JPEG_ENCODING,
    Frame,
    FrameError,
    check_frame,
    decode_image,
)
from services.runtime.local_delivery import LocalHub, hub_for
from services.runtime.mailbox import Rejections, Subscription
from services.runtime.session import Limits

M = TypeVar("M", bound=Message)



class _FrameSubscription(Subscription[Any]):
    """Holds (header, payload or decoded image, receive time, key); copies raw pixels only
    when a frame is taken."""

    def __init__(self, loop: asyncio.AbstractEventLoop, maxlen: int,
                 rejections: Rejections) -> None:
        super().__init__(loop, maxlen)
        self._rejections = rejections

    def get_nowait(self) -> Frame | None:  # type: ignore[override]
        while (item := super().get_nowait()) is not None:
            header, payload, received_ns, key = item
            if isinstance(payload, np.ndarray):  # decoded on the frame thread
                return Frame(header, payload, received_ns)
            data = payload if isinstance(payload, bytes) else payload.to_bytes()
            try:
                return Frame(header, decode_image(header, data), received_ns)
            except FrameError as err:
                self._rejections.add(key, str(err))
        return None


class Bus:
    """One service's typed view of a shared Zenoh session.

    Args:
        session: an open Zenoh session (owned by the caller).
        keys: the key table for the deployment's namespace.
        service: the service name, used for logs and the ``alive/<service>`` token.
        rejections: where rejected payloads are counted (the launcher keeps one per service
            across restarts); a fresh count by default.
        limits: sizes beyond which payloads are refused before parsing or decoding.
        local_delivery: this bus's subscriptions take messages published by buses of the
            same session straight from them (``services.runtime.local_delivery``); False
            takes everything from Zenoh. Publishing always serves both kinds of subscriber.
    """

    def __init__(self, session: zenoh.Session, keys: Keys | None = None,
                 service: str = "client", rejections: Rejections | None = None,
                 local_delivery: bool = True, limits: Limits | None = None) -> None:
        self.session = session
        self.keys = keys or Keys()
        self.service = service
        self.log = logging.getLogger(f"shepherd.{service}")
        self.rejections = rejections or Rejections(self.log)
        self.local_delivery = local_delivery
        self.limits = limits or Limits()
        self._closers: list[Callable[[], None]] = []
        self._publishers: dict[str, Any] = {}
        self._hub: LocalHub = hub_for(session)

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

    def declare_token(self, key_expr: str) -> None:
        """Declare a liveliness token on any key until this bus closes."""
        token = self.session.liveliness().declare_token(key_expr)
        self._closers.append(token.undeclare)

    def raw_publisher(self, key_expr: str, *, cache: int = 0) -> Any:
        """A Zenoh publisher on any key (for foreign wire formats), undeclared with the bus;
        ``cache`` > 0: a zenoh-ext advanced publisher keeping that many samples for late
        subscribers, detectable by them, with a sporadic heartbeat (0.5 s) for their
        recovery of missed samples (rmw_zenoh's reliable transient-local publisher)."""
        pub = (zenoh.ext.declare_advanced_publisher(
            self.session, key_expr, cache=zenoh.ext.CacheConfig(max_samples=cache),
            publisher_detection=True,
            sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=None,
                                                                sporadic_heartbeat=0.5))
            if cache > 0 else self.session.declare_publisher(key_expr))
        self._closers.append(pub.undeclare)
        return pub

    def raw_queryable(self, key_expr: str, on_query: Callable[[zenoh.Query], None]) -> None:
        """A complete Zenoh queryable on any key (for foreign wire formats), undeclared with
        the bus; ``on_query`` runs on Zenoh's thread."""
        q = self.session.declare_queryable(key_expr, on_query, complete=True)
        self._closers.append(q.undeclare)

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

    def has_subscribers(self, suffix: str, encoding: str) -> bool:
        """Whether any subscriber (in this process or elsewhere) matches ``<namespace>/<suffix>``
        now, as Zenoh's publisher matching status sees it."""
        key = self.keys.key(suffix)
        return bool(self._publisher(key, encoding).matching_status.matching)

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
                self.rejections.add(
                    key, f"encoding {got!r}, expected {model.zenoh_encoding()!r}")
        return deliver

    def decode(self, sample: zenoh.Sample, model: type[M]) -> M | None:
        """Validate a JSON sample against ``model``; count and return None when invalid."""
        key = str(sample.key_expr)
        schema = str(sample.encoding)
        if ";shepherd." in schema and schema != model.zenoh_encoding():
            self.rejections.add(key, f"encoding {schema!r}, expected {model.zenoh_encoding()!r}")
            return None
        if len(sample.payload) > self.limits.max_json_bytes:
            self.rejections.add(key, f"{model.__name__} payload of {len(sample.payload)} bytes "
                                f"exceeds the {self.limits.max_json_bytes}-byte limit")
            return None
        try:
            return model.model_validate_json(sample.payload.to_bytes())
        except ValidationError as err:
            self.rejections.add(key, f"invalid {model.__name__}: "
                                f"{describe_validation_error(err, show_input=False)}")
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

        sub.bind(self._declare(key_expr or self.keys.key(suffix), on_sample,
                               self._typed_local(model, sub.push)))
        return sub

    def subscribe_stamped(self, suffix: str, model: type[M], *, queue: int = 256,
                          clock: Callable[[], int] = time.time_ns
                          ) -> Subscription[tuple[int, M]]:
        """Bounded queue of (receive time ns by ``clock``, Unix time by default, message):
        for latency measurements and arrival cadences."""
        sub: Subscription[tuple[int, M]] = Subscription(asyncio.get_running_loop(), queue)

        def on_sample(sample: zenoh.Sample) -> None:
            msg = self.decode(sample, model)
            if msg is not None:
                sub.push((clock(), msg))

        sub.bind(self._declare(self.keys.key(suffix), on_sample, self._typed_local(
            model, lambda msg: sub.push((clock(), msg)))))
        return sub

    def frame_header(self, sample: zenoh.Sample) -> FrameHeader | None:
        """Validate a ``camera/frame`` sample's header, size and (JPEG) dimensions without
        decoding it; count and return None when invalid."""
        attachment = sample.attachment.to_bytes() if sample.attachment is not None else None
        try:
            return check_frame(attachment, len(sample.payload), sample.payload.to_bytes,
                               self.limits.max_frame_side)
        except FrameError as err:
            self.rejections.add(str(sample.key_expr), str(err))
            return None

    def decode_frame(self, sample: zenoh.Sample) -> Frame | None:
        """Decode a ``camera/frame`` sample now; count and return None when invalid."""
        header = self.frame_header(sample)
        if header is None:
            return None
        try:
            image = decode_image(header, sample.payload.to_bytes())
        except FrameError as err:
            self.rejections.add(str(sample.key_expr), str(err))
            return None
        return Frame(header, image, time.time_ns())

    def subscribe_frames(self, *, latest: bool = True, queue: int = 2) -> Subscription[Frame]:
        """Frames, newest first. Zenoh keeps them in a ring of the policy's size, so under a
        flood stale frames are dropped before they reach Python; a reader thread validates
        each header and size on receipt (and decodes JPEGs, off the event loop); raw pixels
        are copied only when taken."""
        size = 1 if latest else queue
        sub = _FrameSubscription(asyncio.get_running_loop(), size, self.rejections)
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
                key = str(sample.key_expr)
                try:
                    header = self.frame_header(sample)
                    if header is None:
                        continue
                    payload: Any = sample.payload
                    if header.encoding is FrameEncoding.JPEG:
                        payload = decode_image(header, payload.to_bytes())
                    sub.push((header, payload, time.time_ns(), key))
                except FrameError as err:
                    self.rejections.add(key, str(err))
                except Exception as err:  # never let one sample stop the frames
                    self.rejections.add(key, f"frame not taken: {type(err).__name__}: {err}")

        threading.Thread(target=pump, name=f"frames-{self.service}", daemon=True).start()
        undeclared = threading.Event()

        def undeclare() -> None:
            if not undeclared.is_set():
                undeclared.set()
                remove_local()
                zsub.undeclare()

        self._closers.append(undeclare)
        sub.bind(undeclare)
        return sub  # type: ignore[return-value]

    def subscribe_raw(self, key_expr: str, *, queue: int = 256) -> Subscription[zenoh.Sample]:
        """Untyped samples on any key expression (for ``echo`` and recording)."""
        sub: Subscription[zenoh.Sample] = Subscription(asyncio.get_running_loop(), queue)
        sub.bind(self._declare(key_expr, sub.push))
        return sub

    def subscribe_liveliness(self, key_expr: str, *, queue: int = 16
                             ) -> Subscription[tuple[str, bool]]:
        """Liveliness tokens matching ``key_expr`` as (key, alive): True when one appears
        (including those already up), False when one goes away."""
        sub: Subscription[tuple[str, bool]] = Subscription(asyncio.get_running_loop(), queue)

        def on_sample(sample: zenoh.Sample) -> None:
            sub.push((str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT))

        zsub = self.session.liveliness().declare_subscriber(key_expr, on_sample, history=True)
        self._closers.append(zsub.undeclare)
        sub.bind(zsub.undeclare)
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
