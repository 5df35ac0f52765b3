"""Random, seeded views of the marker with known truth, for tests and benchmarks."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np

from services.core.camera import CameraModel
from services.core.geometry import inv_T, make_T, rot_z
from services.core.mounts import Geometry
from services.sim.render import INKS_BGR, Rendered, RenderStyle, render_view
from services.sim.webcam import WebcamParams


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def facing_rotation(ray: np.ndarray) -> np.ndarray:
    """Marker rotation (in the camera frame) whose normal points back along ``ray``, y up."""
    z = -ray / np.linalg.norm(ray)
    up = np.array([0.0, -1.0, 0.0])
    y = up - (up @ z) * z
    y /= np.linalg.norm(y)
    return np.column_stack([np.cross(y, z), y, z])


def marker_pose(distance_m: float, u: float, v: float, camera: CameraModel,
                off_normal_rad: float = 0.0, tilt_azimuth_rad: float = 0.0,
                roll_rad: float = 0.0) -> np.ndarray:
    """T_camera_marker: marker centre on the ray through pixel (u, v) at ``distance_m``,
    turned ``off_normal_rad`` away from the line of sight about an in-plane axis at
    ``tilt_azimuth_rad`` (0 = about the marker's vertical axis), rolled ``roll_rad``."""
    ray = np.linalg.solve(camera.K, [u, v, 1.0])
    ray /= np.linalg.norm(ray)
    axis = np.array([np.sin(tilt_azimuth_rad), np.cos(tilt_azimuth_rad), 0.0])
    R = facing_rotation(ray) @ _axis_angle(axis, off_normal_rad) @ rot_z(roll_rad)
    return make_T(R, distance_m * ray)


@dataclass(frozen=True)
class View:
    """A rendered view with its parameters."""

    rendered: Rendered
    distance_m: float
    off_normal_rad: float
    roll_rad: float
    style: RenderStyle


def random_webcam(rng: np.random.Generator, **fixed: object) -> WebcamParams:
    """A webcam as one might meet it: optics blur 0.3-0.9 px, RGGB Bayer demosaiced by OpenCV,
    shot and read noise, white balance off by up to 4 % per channel, exposure 0.55-0.95 (auto
    exposure keeps white below clipping), sRGB,
    8 bits, JPEG at quality 75-95 on half of the frames. ``fixed`` overrides any field."""
    values: dict[str, object] = dict(
        blur_sigma_px=rng.uniform(0.3, 0.9), exposure=rng.uniform(0.55, 0.95),
        full_well_e=rng.uniform(2000, 8000), read_noise_e=rng.uniform(2, 10),
        white_balance=tuple(float(g) for g in rng.uniform(0.96, 1.04, 3)),
        jpeg_quality=int(rng.integers(75, 96)) if rng.random() < 0.5 else 0)
    values.update(fixed)
    return WebcamParams.model_validate(values)


def random_views(n: int, seed: int = 0, *, camera: CameraModel | None = None,
                 geometry: Geometry | None = None, distance_m: tuple[float, float] = (0.15, 0.8),
                 max_off_normal_deg: float = 50.0, max_roll_deg: float = 15.0,
                 noise_sigma: tuple[float, float] = (1.0, 4.0), blur_probability: float = 0.3,
                 brightness: tuple[float, float] = (0.5, 1.0), margin_px: float = 8.0,
                 clutter: bool = True, webcam: dict[str, object] | bool = False,
                 ink: str = "nominal") -> Iterator[View]:
    """Seeded random views of a wholly visible marker (plus the humanoid body behind it).

    ``webcam``: render through ``random_webcam`` (a dict fixes some of its fields) in
    photographed rooms, the body behind the marker on half of the views; ``ink`` names the
    marker's ink (``render.INKS_BGR``)."""
    camera = camera or CameraModel.paper()
    geometry = geometry or Geometry()
    pts = geometry.marker_points()
    T_marker_humanoid = inv_T(geometry.T_humanoid_marker())
    rng = np.random.default_rng(seed)
    made = 0
    while made < n:
        d = rng.uniform(*distance_m)
        a = np.radians(rng.uniform(0, max_off_normal_deg))
        az = rng.uniform(-np.pi / 2, np.pi / 2) * (1 if rng.random() < 0.3 else 0.25)
        roll = np.radians(rng.uniform(-max_roll_deg, max_roll_deg))
        u = rng.uniform(0.15, 0.85) * camera.width
        v = rng.uniform(0.15, 0.85) * camera.height
        T = marker_pose(d, u, v, camera, a, az, roll)
        corners = camera.project((T[:3, :3] @ pts.T).T + T[:3, 3])
        if np.any(corners < margin_px) or np.any(corners > [camera.width - 1 - margin_px,
                                                           camera.height - 1 - margin_px]):
            continue
        blur = rng.uniform(1.0, 3.0) if rng.random() < blur_probability else 0.0
        style = RenderStyle(seed=int(rng.integers(0, 6)), brightness=rng.uniform(*brightness),
                            noise_sigma=rng.uniform(*noise_sigma), motion_blur_px=blur,
                            motion_blur_angle_deg=rng.uniform(0, 180), clutter=clutter,
                            distractors=clutter, marker_bgr=INKS_BGR[ink])
        if webcam is not False:
            style = replace(style, seed=int(rng.integers(0, 1 << 30)), noise_sigma=0.0,
                            camera=random_webcam(rng, **(webcam if isinstance(webcam, dict)
                                                         else {})),
                            photos=True, draw_body=bool(rng.random() < 0.5))
        r = render_view(camera, T, marker_points_m=pts, T_camera_humanoid=T @ T_marker_humanoid,
                        style=style, frame_index=made)
        made += 1
        yield View(r, d, a, roll, style)
