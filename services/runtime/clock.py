"""Time on this host: a message's age, and drift-free periodic loops.

Ages are measured from when a message *arrived on this host* (``Subscription.last_received_ns``),
never from the sender's stamp, so a clock offset between hosts can neither freeze a consumer
nor hide a stale message.
"""

from __future__ import annotations

import asyncio
import time
from collections import deque


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


class LagFloor:
    """How much later than the fastest of its stream a message arrived, without clock sync.

    A message's lag is its arrival on this host minus the sender's stamp: the one-way delay
    plus an unknown, constant offset between the two clocks. The smallest lag over the last
    ``window_s`` of arrivals is the floor (the fastest delivery seen, offset included); a
    message's ``excess_s`` is its lag above that floor, i.e. how long it waited beyond the
    stream's best: a message held in a buffer during a network cut shows its whole wait. The
    window forgets, so a lasting rise of the network's delay (or a step of either clock) makes
    messages look late for at most ``window_s``; it never makes a late message look fresh
    unless the whole window is made of late ones (e.g. the first messages after a gap longer
    than the window: pair this with a check of the arrival cadence).
    """

    def __init__(self, window_s: float = 10.0) -> None:
        if window_s <= 0:
            raise ValueError(f"a lag floor needs a positive window, got {window_s}")
        self.window_s = window_s
        self._lags: deque[tuple[float, float]] = deque()  # (arrival s, lag s), lags rising

    def excess_s(self, sent_s: float, arrival_s: float) -> float:
        """Record one message (sender's clock ``sent_s``, this host's ``arrival_s``, both in
        seconds) and return its lag above the floor (>= 0)."""
        lag = arrival_s - sent_s
        lags = self._lags
        while lags and lags[-1][1] >= lag:  # monotonic deque: the front is the window's min
            lags.pop()
        lags.append((arrival_s, lag))
        while lags[0][0] < arrival_s - self.window_s:
            lags.popleft()
        return lag - lags[0][1]

    def reset(self) -> None:
        self._lags.clear()
