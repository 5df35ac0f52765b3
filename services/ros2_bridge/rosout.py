"""Shepherd's log records at WARNING and above, kept for /rosout (no Zenoh inside)."""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Iterator

#: the records kept between two drains (rcl's /rosout depth)
DEPTH = 1000


class RosoutHandler(logging.Handler):
    """Keeps the records of a logger tree (thread-safe) until the bridge publishes them."""

    def __init__(self, level: int = logging.WARNING) -> None:
        super().__init__(level)
        self.records: deque[logging.LogRecord] = deque(maxlen=DEPTH)

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)

    def drain(self) -> Iterator[logging.LogRecord]:
        while self.records:
            yield self.records.popleft()
