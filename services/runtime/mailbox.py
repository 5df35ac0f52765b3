"""Bounded mailboxes from Zenoh's threads into asyncio, and the count of rejected payloads.

A :class:`Subscription` keeps at most ``maxlen`` items: ``maxlen=1`` is the latest-value
policy, larger values a queue that drops the oldest. The Zenoh thread appends and schedules at
most one wake-up of the event loop, so nothing builds an unbounded backlog.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections import Counter, deque
from collections.abc import AsyncIterator, Callable
from typing import Generic, TypeVar

T = TypeVar("T")


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
    """A bounded mailbox fed from any thread and read from asyncio.

    ``dropped`` counts items overwritten before being read; ``last_received_ns`` is the Unix
    time (this host's clock) at which the newest item arrived.
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
        self.last_received_ns = 0
        self._undeclare: Callable[[], None] = _nothing
        self._loop_thread = threading.get_ident()  # created in the running loop

    def bind(self, undeclare: Callable[[], None]) -> None:
        """What :meth:`close` undoes (the declaration that feeds this mailbox)."""
        self._undeclare = undeclare

    def push(self, item: T) -> None:
        """Called from any thread: store the item and wake the reader (at most one pending)."""
        with self._lock:
            if len(self._items) == self._items.maxlen:
                self.dropped += 1
            self._items.append(item)
            self.received += 1
            self.last_received_ns = time.time_ns()
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


def _nothing() -> None:
    pass
