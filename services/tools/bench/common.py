"""What every bench section shares: tables, timing, progress, a free loopback endpoint."""

from __future__ import annotations

import math
import socket
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

#: The real calibration data sets of a clone (``tests/data``; not in an installed wheel).
DATASETS = Path(__file__).resolve().parents[3] / "tests" / "data"

Row = tuple[str, ...]


def table(header: Row, rows: Sequence[Row]) -> str:
    widths = [max(len(str(r[i])) for r in (header, *rows)) for i in range(len(header))]
    line = "| " + " | ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)) + " |"
    sep = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    body = ["| " + " | ".join(str(c).ljust(w) for c, w in zip(r, widths, strict=True)) + " |"
            for r in rows]
    return "\n".join([line, sep, *body])


def section(title: str, header: Row, rows: Sequence[Row], note: str = "") -> None:
    print(f"\n## {title}\n\n{table(header, rows)}")
    if note:
        print(f"\n{note}")
    sys.stdout.flush()


def times_us(fn: Callable[..., object], n: int, *args: object) -> np.ndarray:
    """Wall time of ``fn(*args)`` in µs, ``n`` calls."""
    out = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter_ns()
        fn(*args)
        out[i] = (time.perf_counter_ns() - t0) / 1e3
    return out


def machine_ms() -> float:
    """The machine's speed: ms for 10⁶ additions in a pure-Python loop, the best of 5."""
    best = math.inf
    for _ in range(5):
        t0 = time.perf_counter()
        total = 0
        for i in range(1_000_000):
            total += i
        best = min(best, time.perf_counter() - t0)
    return 1e3 * best


def endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def progress(what: str) -> None:
    print(f"  … {what}", file=sys.stderr, flush=True)
