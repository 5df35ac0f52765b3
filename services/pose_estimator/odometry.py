"""Camera-robot odometry at a frame's stamp: a short history, interpolated.

Poses are the base's (x m, y m, yaw rad) on the floor in the world frame; stamps are ns.
"""

from __future__ import annotations

import math
from collections import deque

from schemas import CameraPose


class OdometryBuffer:
    """The last ``maxlen`` odometry samples, kept in stamp order."""

    def __init__(self, maxlen: int = 64) -> None:
        self.samples: deque[CameraPose] = deque(maxlen=maxlen)

    def add(self, pose: CameraPose) -> None:
        """Insert ``pose``; out-of-order samples go to their place, a repeated stamp replaces."""
        s = self.samples
        if not s or pose.stamp_ns > s[-1].stamp_ns:
            s.append(pose)
            return
        for i in range(len(s) - 1, -1, -1):
            if s[i].stamp_ns == pose.stamp_ns:
                s[i] = pose
                return
            if s[i].stamp_ns < pose.stamp_ns:
                if len(s) == s.maxlen:  # full: the oldest goes to make room
                    s.popleft()
                    i -= 1
                s.insert(i + 1, pose)
                return
        if len(s) < s.maxlen:  # type: ignore[operator]
            s.appendleft(pose)  # older than everything held, and there is room

    def covers(self, stamp_ns: int) -> bool:
        """True once a sample at or after ``stamp_ns`` is held (interpolation needs no more)."""
        return bool(self.samples) and self.samples[-1].stamp_ns >= stamp_ns

    def at(self, stamp_ns: int, max_gap_s: float) -> tuple[tuple[float, float, float] | None, str]:
        """(x, y, yaw) at ``stamp_ns``, or None and why.

        Between two samples the pose is interpolated (yaw the short way round); outside them the
        nearest sample is held, if it is within ``max_gap_s`` of the stamp.
        """
        s = self.samples
        if not s:
            return None, "no camera odometry received"
        after = None
        for i in range(len(s) - 1, -1, -1):
            o = s[i]
            if o.stamp_ns == stamp_ns:
                return (o.x, o.y, o.yaw), ""
            if o.stamp_ns < stamp_ns:
                if after is not None:
                    w = (stamp_ns - o.stamp_ns) / (after.stamp_ns - o.stamp_ns)
                    dyaw = math.remainder(after.yaw - o.yaw, math.tau)
                    return (o.x + w * (after.x - o.x), o.y + w * (after.y - o.y),
                            math.remainder(o.yaw + w * dyaw, math.tau)), ""
                break
            after = o
        nearest = min((s[-1], s[0]), key=lambda o: abs(o.stamp_ns - stamp_ns))
        gap_s = abs(stamp_ns - nearest.stamp_ns) / 1e9
        if gap_s > max_gap_s:
            return None, f"camera odometry is {gap_s:.2f} s from the frame"
        return (nearest.x, nearest.y, nearest.yaw), ""
