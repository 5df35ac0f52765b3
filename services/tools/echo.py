"""``shepherd echo`` and one-shot publishing for the CLI."""

from __future__ import annotations

import asyncio
import sys
import time

from schemas import Keys, Message
from schemas.keys import model_or_none
from services.runtime.bus import Bus
from services.runtime.session import ZenohSettings, open_session
from services.tools.pretty import describe, printable


async def echo(settings: ZenohSettings, namespace: str, key_expr: str, *,
               count: int | None = None, duration: float | None = None,
               raw: bool = False) -> int:
    """Print every message on ``key_expr``, decoded and readable, one line each."""
    keys = Keys(namespace)
    seen = 0
    frame_times: list[float] = []
    with open_session(settings) as session:
        bus = Bus(session, keys, "echo")
        samples = bus.subscribe_raw(key_expr)
        deadline = None if duration is None else time.monotonic() + duration
        try:
            while count is None or seen < count:
                timeout = None if deadline is None else max(0.0, deadline - time.monotonic())
                try:
                    sample = await samples.recv(timeout)
                except TimeoutError:
                    break
                key = str(sample.key_expr)
                suffix = keys.suffix(key)
                model = model_or_none(suffix)
                if suffix == "camera/frame":  # checked, never decoded: nothing to allocate
                    h = bus.frame_header(sample)
                    now = time.monotonic()
                    frame_times = [t for t in frame_times if now - t < 2.0] + [now]
                    rate = (len(frame_times) - 1) / max(now - frame_times[0], 1e-9)
                    line = ("invalid frame (see warning)" if h is None else
                            f"seq={h.seq} {h.width}x{h.height} {h.encoding.value} "
                            f"{len(sample.payload) / 1e3:.1f} kB {rate:.1f} fps")
                elif len(sample.payload) > bus.limits.max_json_bytes:
                    line = (f"{len(sample.payload)} bytes, over the "
                            f"{bus.limits.max_json_bytes}-byte limit: not shown")
                elif model is not None and not raw:
                    msg = bus.decode(sample, model)
                    line = "invalid (see warning)" if msg is None else describe(msg)
                else:
                    line = sample.payload.to_bytes().decode(errors="replace")
                print(printable(f"{suffix}: {line}"), flush=True)
                seen += 1
        finally:
            bus.close()
    return 0


async def publish_once(settings: ZenohSettings, namespace: str, suffix: str,
                       message: Message, wait_s: float = 3.0) -> int:
    """Publish one message once a subscriber matches its key (waiting up to ``wait_s``; with
    none by then, it is published anyway and a warning names the key)."""
    with open_session(settings) as session:
        bus = Bus(session, Keys(namespace), "cli")
        deadline = time.monotonic() + wait_s
        while not bus.has_subscribers(suffix, message.zenoh_encoding()):
            if time.monotonic() > deadline:
                print(f"shepherd: warning: nothing subscribes to {bus.keys.key(suffix)} "
                      f"after {wait_s:.0f} s (is the service running and connected?)",
                      file=sys.stderr)
                break
            await asyncio.sleep(0.05)
        await asyncio.sleep(0.05)  # the subscriber's side of the match
        bus.put(suffix, message)
        print(printable(f"{suffix}: {describe(message)}"))
        await asyncio.sleep(0.1)
        bus.close()
    return 0
