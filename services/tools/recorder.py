"""``shepherd record`` and ``shepherd replay``: bus traffic to and from MCAP files.

One MCAP channel per key. JSON messages keep their bytes, with the model's JSON Schema
(encoding ``jsonschema``) so any MCAP viewer can decode them. Frames are stored losslessly
as ``shepherd.frame``: a 4-byte big-endian header length, the FrameHeader JSON, then the
payload (raw pixels, or JPEG when recorded with ``--jpeg Q``). Log time is the receive time;
replay publishes at the recorded pace (or ``speed`` times faster), without the keys that
move a robot unless asked, and optionally under another namespace.
"""

from __future__ import annotations

import asyncio
import json
import struct
import time
from collections.abc import Callable
from pathlib import Path

import zenoh
from mcap.reader import make_reader
from mcap.writer import Writer

from schemas import Keys
from schemas.keys import ACTUATION, model_or_none
from services.runtime.bus import Bus
from services.runtime.frames import FRAME_ENCODING, JPEG_ENCODING, encode_frame
from services.runtime.session import ZenohSettings, open_session

FRAME_MESSAGE_ENCODING = "shepherd.frame"


def pack_frame(header_json: bytes, payload: bytes) -> bytes:
    return struct.pack(">I", len(header_json)) + header_json + payload


def unpack_frame(data: bytes) -> tuple[bytes, bytes]:
    (n,) = struct.unpack(">I", data[:4])
    return data[4:4 + n], data[4 + n:]


async def record(settings: ZenohSettings, namespace: str, out: Path, key_exprs: list[str],
                 duration: float | None = None, jpeg_quality: int | None = None,
                 log=print) -> int:
    keys = Keys(namespace)
    exprs = key_exprs or [f"{namespace}/**"]
    written = 0
    with open_session(settings) as session, open(out, "wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="shepherd")
        channels: dict[str, int] = {}
        schemas: dict[str, int] = {}
        bus = Bus(session, keys, "recorder")
        subs = [bus.subscribe_raw(e, queue=4096) for e in exprs]

        def channel_for(key: str) -> int:
            if key in channels:
                return channels[key]
            suffix = keys.suffix(key)
            model = model_or_none(suffix)
            if suffix == "camera/frame":
                cid = writer.register_channel(key, FRAME_MESSAGE_ENCODING, 0)
            elif model is not None:
                if model.__name__ not in schemas:
                    schemas[model.__name__] = writer.register_schema(
                        f"shepherd.{model.__name__}", "jsonschema",
                        json.dumps(model.model_json_schema()).encode())
                cid = writer.register_channel(key, "json", schemas[model.__name__])
            else:
                cid = writer.register_channel(key, "", 0)
            channels[key] = cid
            return cid

        deadline = None if duration is None else time.monotonic() + duration
        last_report = time.monotonic()
        try:
            while deadline is None or time.monotonic() < deadline:
                got = False
                for sub in subs:
                    while (s := sub.get_nowait()) is not None:
                        got = True
                        key = str(s.key_expr)
                        data = s.payload.to_bytes()
                        if keys.suffix(key) == "camera/frame":
                            frame = bus.decode_frame(s)
                            if frame is None:
                                continue
                            header = s.attachment.to_bytes() if s.attachment else b"{}"
                            if jpeg_quality is not None and frame.header.encoding.value != "jpeg":
                                h, data = encode_frame(frame.image, frame.header.seq,
                                                       frame.header.stamp_ns, jpeg_quality)
                                header = h.model_dump_json().encode()
                            data = pack_frame(header, data)
                        now = time.time_ns()
                        writer.add_message(channel_for(key), log_time=now, data=data,
                                           publish_time=now)
                        written += 1
                if time.monotonic() - last_report > 2.0:
                    log(f"recorded {written} messages on {len(channels)} keys")
                    last_report = time.monotonic()
                if not got:
                    await asyncio.sleep(0.005)
        except (KeyboardInterrupt, asyncio.CancelledError):
            pass
        finally:
            dropped = sum(s.dropped for s in subs)
            bus.close()
            writer.finish()
    log(f"wrote {out}: {written} messages on {len(channels)} keys"
        + (f", {dropped} dropped (recorder too slow)" if dropped else ""))
    return 0


def is_actuation(key: str, namespace: str = "shepherd") -> bool:
    """A key that moves a robot (``ir/**``, ``mission/**``, ``camera/goal``)."""
    prefix = namespace + "/"
    if not key.startswith(prefix):
        return False
    ke = zenoh.KeyExpr(key[len(prefix):])
    return any(zenoh.KeyExpr(a).intersects(ke) for a in ACTUATION)


async def replay(settings: ZenohSettings, inp: Path, speed: float = 1.0,
                 only: list[str] | None = None, log: Callable[[str], None] = print, *,
                 namespace: str = "shepherd", to_namespace: str | None = None,
                 actuate: bool = False) -> int:
    """Publish a recording back at its recorded pace (times ``speed``). Keys that move a robot
    are left out unless ``actuate``; ``to_namespace`` republishes ``<namespace>/...`` under
    ``<to_namespace>/...``."""
    if to_namespace is not None:
        Keys(to_namespace)  # raises ValueError for an unusable namespace
    published = skipped = 0
    with open_session(settings) as session, open(inp, "rb") as f:
        reader = make_reader(f)
        await asyncio.sleep(0.5)  # let subscribers be discovered
        start_wall = time.monotonic()
        start_log = None
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            key = channel.topic
            if only and not any(zenoh.KeyExpr(o).intersects(zenoh.KeyExpr(key)) for o in only):
                continue
            if not actuate and is_actuation(key, namespace):
                skipped += 1
                continue
            if to_namespace is not None and key.startswith(namespace + "/"):
                key = f"{to_namespace}/{key[len(namespace) + 1:]}"
            if start_log is None:
                start_log = message.log_time
            due = (message.log_time - start_log) / 1e9 / speed
            delay = due - (time.monotonic() - start_wall)
            if delay > 0:
                await asyncio.sleep(delay)
            if channel.message_encoding == FRAME_MESSAGE_ENCODING:
                header, payload = unpack_frame(message.data)
                enc = JPEG_ENCODING if b'"jpeg"' in header else FRAME_ENCODING
                session.put(key, payload, attachment=header, encoding=zenoh.Encoding(enc))
            else:
                model: str | None = None
                if schema is not None and schema.name.startswith("shepherd."):
                    model = schema.name.removeprefix("shepherd.")
                json_enc = f"application/json;shepherd.{model}/1" if model else None
                session.put(key, message.data,
                            encoding=zenoh.Encoding(json_enc) if json_enc else None)
            published += 1
        await asyncio.sleep(0.2)
    log(f"replayed {published} messages from {inp}"
        + (f"; left out {skipped} on actuation keys (ir/**, mission/**, camera/goal: "
           "--actuate to include them)" if skipped else ""))
    return 0
