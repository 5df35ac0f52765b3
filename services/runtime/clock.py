"""Time on this host: a message's age, and drift-free periodic loops.

Ages are measured from when a message *arrived on this host* (``Subscription.last_received_ns``),
never from the sender's stamp, so a clock offset between hosts can neither freeze a consumer
nor hide a stale message.
"""

from __future__ import annotations

import asyncio
import time


def age_s(since_ns: int, now_ns: int | None = None) -> float:
    """Seconds from ``since_ns`` (Unix ns on this host's clock) to now; inf when never."""
    if since_ns <= 0:
        return float("inf")
    return ((time.time_ns() if now_ns is None else now_ns) - since_ns) / 1e9


class Ticker:
    """Waits out a fixed period between loop iterations without drifting; after falling
    more than ``resync_s`` behind it starts afresh rather than bursting to catch up."""

    def __init__(self, period_s: float, resync_s: float = 0.5) -> None:
        if period_s <= 0:
            raise ValueError(f"a ticker needs a positive period, got {period_s}")
        self.period_s = period_s
        self.resync_s = resync_s
        self._next = time.monotonic()

    async def wait(self) -> None:
        """Sleep until the next tick."""
        self._next += self.period_s
        delay = self._next - time.monotonic()
        if delay < -self.resync_s:
            self._next = time.monotonic()
        await asyncio.sleep(max(0.0, delay))
