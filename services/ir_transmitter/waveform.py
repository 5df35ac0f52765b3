"""Decode a traced IR pin (carrier bursts) back into Robosapien frames: for checking the
microcontroller firmware in simavr."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.ir_transmitter.protocol import decode_timings


@dataclass(frozen=True)
class Frame:
    code: int
    durations_us: list[float]   # mark, space, mark, ... as the LED is on / off
    carrier_hz: float           # mean over the frame's marks


def bursts(edges_s: np.ndarray, levels: np.ndarray, max_gap_s: float = 100e-6
           ) -> list[tuple[float, float, int]]:
    """Carrier bursts (start s, end s, rising edges) from pin edges (time s, level 0/1)."""
    rising = edges_s[(levels == 1) & (np.r_[0, levels[:-1]] == 0)]
    falling = edges_s[(levels == 0) & (np.r_[1, levels[:-1]] == 1)]
    if not len(rising):
        return []
    out = []
    start = prev = rising[0]
    count = 1
    for t in rising[1:]:
        if t - prev > max_gap_s:
            out.append((start, prev, count))
            start, count = t, 0
        count += 1
        prev = t
    out.append((start, prev, count))
    # end a burst at the falling edge after its last rising edge
    ends = []
    for s, last, n in out:
        after = falling[falling > last]
        ends.append((s, float(after[0]) if len(after) else last, n))
    return ends


def decode_trace(edges_s: np.ndarray, levels: np.ndarray, frame_gap_s: float = 0.02
                 ) -> list[Frame]:
    """Frames in a pin trace; each burst is a mark, the time between bursts a space."""
    bs = bursts(edges_s, levels)
    frames: list[list[tuple[float, float, int]]] = []
    for b in bs:
        if frames and b[0] - frames[-1][-1][1] < frame_gap_s:
            frames[-1].append(b)
        else:
            frames.append([b])
    out = []
    for fr in frames:
        durations: list[float] = []
        freqs = []
        for i, (s, e, n) in enumerate(fr):
            if i:
                durations.append((s - fr[i - 1][1]) * 1e6)
            period = (e - s) / max(n - 0.5, 1)  # n rising edges span n - 1/2 periods
            durations.append((e - s) * 1e6 + 0.0)
            freqs.append(1.0 / period if period > 0 else 0.0)
        out.append(Frame(decode_timings([round(d) for d in durations], tolerance=0.05),
                         durations, float(np.mean(freqs))))
    return out
