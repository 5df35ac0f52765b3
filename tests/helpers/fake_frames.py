"""A fake frame publisher for loopback tests: simulator renders with known truth."""

from __future__ import annotations

import time

import numpy as np

from services.core.camera import CameraModel
from services.core.geometry import inv_T
from services.core.mounts import Geometry
from services.runtime.bus import Bus
from services.runtime.frames import encode_frame
from services.sim.render import Rendered, RenderStyle, render_view
from services.sim.scenes import marker_pose


def render_marker(distance_m: float = 0.3, u: float = 320, v: float = 240,
                  off_normal_deg: float = 10.0, seed: int = 0) -> Rendered:
    cam, g = CameraModel.paper(), Geometry()
    T = marker_pose(distance_m, u, v, cam, np.radians(off_normal_deg))
    return render_view(cam, T, marker_points_m=g.marker_points(),
                       T_camera_humanoid=T @ inv_T(g.T_humanoid_marker()),
                       style=RenderStyle(seed=seed))


def publish_frame(bus: Bus, image: np.ndarray, seq: int) -> None:
    header, payload = encode_frame(image, seq, time.time_ns())
    bus.put_frame(header, payload)
