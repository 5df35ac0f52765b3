"""One-line, human-readable renderings of bus messages (cm, degrees, ms)."""

from __future__ import annotations

import math
import time
import unicodedata

from schemas import (
    CameraGoal,
    CameraPose,
    Hold,
    HumanoidPose,
    IrCommand,
    MarkerVertices,
    Message,
    MissionState,
    SimTruth,
)


def cm(x: float | None) -> str:
    return "—" if x is None else f"{100 * x:.1f} cm"


def deg(a: float | None) -> str:
    return "—" if a is None else f"{math.degrees(a):.1f}°"


def age_ms(stamp_ns: int) -> str:
    return f"{(time.time_ns() - stamp_ns) / 1e6:.1f} ms"


def printable(text: str) -> str:
    """``text`` with control characters (terminal escapes, carriage returns, bidi overrides)
    shown as escapes, so a string from the wire cannot rewrite the terminal."""
    return "".join(c if not unicodedata.category(c).startswith("C") else
                   (f"\\x{ord(c):02x}" if ord(c) < 0x100 else f"\\u{ord(c):04x}")
                   for c in text)


def describe(message: Message) -> str:
    """A readable one-line summary of a message."""
    m = message
    if isinstance(m, HumanoidPose):
        p = m.marker_in_camera.position
        world = (f"x={cm(m.x)} y={cm(m.y)} yaw={deg(m.yaw)}" if m.x is not None
                 else f"world unknown ({m.reason})")
        return (f"seq={m.seq} {world} marker z={cm(p[2])} reproj={m.reprojection_px:.2f} px "
                f"age={age_ms(m.stamp_ns)}")
    if isinstance(m, MarkerVertices):
        if not m.found:
            return f"seq={m.seq} not found: {m.reason}"
        v = " ".join(f"({u:.1f},{w:.1f})" for u, w in m.vertices_px or ())
        return (f"seq={m.seq} found {v} px r={100 * m.area_ratio:.2f}% "
                f"residual={m.residual_px:.3f} px age={age_ms(m.stamp_ns)}")
    if isinstance(m, CameraPose | CameraGoal):
        extra = f" ({m.reason})" if isinstance(m, CameraGoal) and m.reason else ""
        return f"x={cm(m.x)} y={cm(m.y)} yaw={deg(m.yaw)}{extra}"
    if isinstance(m, IrCommand):
        return f"{m.command.value} (0x{m.code:02X})"
    if isinstance(m, MissionState):
        return (f"{m.phase.value} waypoint={m.waypoint_index} e={cm(m.distance_m)} "
                f"alpha={deg(m.heading_error_rad)} last={m.last_command.value}")
    if isinstance(m, Hold):
        return f"hold={m.hold} {m.reason}"
    if isinstance(m, SimTruth):
        h, c = m.humanoid, m.camera
        return (f"humanoid x={cm(h.x)} y={cm(h.y)} yaw={deg(h.yaw)} | "
                f"camera x={cm(c.x)} y={cm(c.y)} yaw={deg(c.yaw)}")
    return m.model_dump_json()
