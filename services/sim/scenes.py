"""Random, seeded views of the marker with known truth, for tests and benchmarks."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace

import numpy as np

from services.core.camera import CameraModel
from services.core.geometry import inv_T, make_T, rot_z
from services.core.mounts import Geometry
from services.sim.hazards import DistractorKind, Hazards
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
                 ink: str = "nominal", min_off_normal_deg: float = 0.0,
                 max_tilt_azimuth_deg: float | None = 25.0,
                 hazard: Callable[[np.random.Generator], dict[str, object]] | None = None,
                 draw_marker: bool = True) -> Iterator[View]:
    """Seeded random views of a wholly visible marker (plus the humanoid body behind it).

    ``webcam``: render through ``random_webcam`` (a dict fixes some of its fields) in
    photographed rooms, the body behind the marker on half of the views; ``ink`` names the
    marker's ink (``render.INKS_BGR``). ``max_tilt_azimuth_deg``: the axis the marker turns
    about stays within this of its vertical axis (the deployment's views: the humanoid turns
    in front of a level camera at about its height); None: any axis on 30 % of the views,
    within 22 degrees on the rest (views the extractor refuses as not the deployment's when
    the vertical diagonal is foreshortened beyond ``ExtractorParams.max_pitch_deg``).
    ``hazard``: draws ``RenderStyle`` and ``WebcamParams`` overrides per view
    (``HARD_CONDITIONS``; keys of ``WebcamParams`` go to the webcam)."""
    camera = camera or CameraModel.paper()
    geometry = geometry or Geometry()
    pts = geometry.marker_points()
    T_marker_humanoid = inv_T(geometry.T_humanoid_marker())
    rng = np.random.default_rng(seed)
    made = 0
    while made < n:
        d = rng.uniform(*distance_m)
        a = np.radians(rng.uniform(min_off_normal_deg, max_off_normal_deg))
        az = rng.uniform(-np.pi / 2, np.pi / 2) * (1 if rng.random() < 0.3 else 0.25)
        if max_tilt_azimuth_deg is not None:
            az = np.radians(rng.uniform(-max_tilt_azimuth_deg, max_tilt_azimuth_deg))
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
        extra = hazard(rng) if hazard is not None else {}
        if webcam is not False or hazard is not None:
            fixed = dict(webcam) if isinstance(webcam, dict) else {}
            fixed.update({k: v for k, v in extra.items() if k in WebcamParams.model_fields})
            style = replace(style, seed=int(rng.integers(0, 1 << 30)), noise_sigma=0.0,
                            camera=random_webcam(rng, **fixed),
                            photos=True, draw_body=bool(rng.random() < 0.5))
            style = replace(style, **{k: v for k, v in extra.items()  # type: ignore[arg-type]
                                      if k not in WebcamParams.model_fields})
        r = render_view(camera, T, marker_points_m=pts, T_camera_humanoid=T @ T_marker_humanoid,
                        style=style, frame_index=made, draw_marker=draw_marker)
        made += 1
        yield View(r, d, a, roll, style)


def _angle_in_marker(rng: np.random.Generator, reach: float) -> tuple[float, float]:
    """A point of the marker's own frame (``hazards``) within ``reach`` of its centre, in the
    rhombus's own metric (|a| + |b| <= reach)."""
    while True:
        a, b = rng.uniform(-reach, reach, 2)
        if abs(a) + abs(b) <= reach:
            return float(a), float(b)


def _occluder(rng: np.random.Generator, target: str) -> dict[str, object]:
    """A limb or bar over one vertex (``target = "vertex"``) or across part of one edge."""
    k = int(rng.integers(4))
    corners = np.array([[-1.0, 0.0], [0.0, -1.0], [1.0, 0.0], [0.0, 1.0]])  # L, T, R, B
    if target == "vertex":
        end = corners[k] * rng.uniform(0.55, 0.72)
        out = corners[k] * 2.2 + rng.normal(0, 0.25, 2)
        width = rng.uniform(0.18, 0.32)
    else:
        p, q = corners[k], corners[(k + 1) % 4]
        t = rng.uniform(0.35, 0.65)
        on_edge = p + t * (q - p)
        normal = on_edge / np.linalg.norm(on_edge)
        end = on_edge * rng.uniform(0.55, 0.75)
        out = on_edge + normal * 1.4 + rng.normal(0, 0.2, 2)
        width = rng.uniform(0.2, 0.4)
    return dict(hazards=Hazards(occluder="limb" if rng.random() < 0.5 else "bar",
                                occluder_from=(float(out[0]), float(out[1])),
                                occluder_to=(float(end[0]), float(end[1])),
                                occluder_width=float(width)))


def _shadow(rng: np.random.Generator, softness: tuple[float, float]) -> dict[str, object]:
    return dict(hazards=Hazards(shadow_factor=0.35, shadow_softness_px=rng.uniform(*softness),
                                shadow_angle_deg=rng.uniform(0, 360),
                                shadow_offset=rng.uniform(-0.5, 0.5)))


def _distractors(rng: np.random.Generator) -> dict[str, object]:
    kinds: tuple[DistractorKind, ...] = ("card", "card", "shirt", "cup", "rhombus")
    return dict(hazards=Hazards(distractors=kinds, distractor_seed=int(rng.integers(1 << 30))))


#: the hard conditions, each alone: name -> (per-view overrides, ``random_views`` arguments)
HARD_CONDITIONS: dict[str, tuple[Callable[[np.random.Generator], dict[str, object]],
                                 dict[str, object]]] = {
    "clean": (lambda rng: {}, {}),
    "motion blur 3-10 px": (lambda rng: dict(motion_blur_px=rng.uniform(3, 10),
                                             motion_blur_angle_deg=rng.uniform(0, 180)), {}),
    "limb or bar over one edge": (lambda rng: _occluder(rng, "edge"), {}),
    "limb or bar over one vertex": (lambda rng: _occluder(rng, "vertex"), {}),
    "hard cast shadow (x0.35)": (lambda rng: _shadow(rng, (0.0, 0.0)), {}),
    "soft cast shadow (x0.35, 8-40 px)": (lambda rng: _shadow(rng, (8.0, 40.0)), {}),
    "specular highlight, clipped": (lambda rng: dict(hazards=Hazards(
        specular_gain=rng.uniform(1.5, 6.0), specular_radius=rng.uniform(0.15, 0.45),
        specular_at=_angle_in_marker(rng, 0.9))), {}),
    "low light (exposure x0.12)": (lambda rng: dict(exposure=0.12 * rng.uniform(0.55, 0.95)),
                                   {}),
    "tungsten, no white balance": (lambda rng: dict(white_balance=(1.0, 0.72, 0.42)), {}),
    "defocus 2-4 px": (lambda rng: dict(hazards=Hazards(defocus_px=rng.uniform(2, 4))), {}),
    "rolling shutter 10-40 px": (lambda rng: dict(hazards=Hazards(
        rolling_shutter_px=rng.choice([-1, 1]) * rng.uniform(10, 40))), {}),
    "small: 25-40 px across": (lambda rng: {}, dict(size_px=(25.0, 40.0))),
    "steep: 55-70 deg": (lambda rng: {}, dict(min_off_normal_deg=55.0, max_off_normal_deg=70.0,
                                              max_tilt_azimuth_deg=20.0)),
    "pink and magenta things in view": (_distractors, {}),
}
NO_MARKER = "distractors, no marker"


def hard_views(condition: str, n: int, seed: int = 0, *, camera: CameraModel | None = None,
               geometry: Geometry | None = None) -> Iterator[View]:
    """Seeded webcam views under one of ``HARD_CONDITIONS`` (or ``NO_MARKER``: the
    distractors without the marker), marker 15-80 cm away, up to 50 degrees off its normal
    about a near-vertical axis (the deployment's views), nominal magenta."""
    camera = camera or CameraModel.paper()
    geometry = geometry or Geometry()
    hazard: Callable[[np.random.Generator], dict[str, object]]
    kwargs: dict[str, object]
    hazard, kwargs = (_distractors, {}) if condition == NO_MARKER else HARD_CONDITIONS[condition]
    args: dict[str, object] = dict(distance_m=(0.15, 0.8), max_off_normal_deg=50.0,
                                   max_tilt_azimuth_deg=25.0, webcam=True,
                                   draw_marker=condition != NO_MARKER)
    args.update(kwargs)
    size = args.pop("size_px", None)
    if isinstance(size, tuple):  # the vertical diagonal's length in px, at the image centre
        f = float(camera.K[1, 1]) * geometry.marker_height_m
        lo_px, hi_px = float(size[0]), float(size[1])
        args["distance_m"] = (f / hi_px, f / lo_px)
        args["max_off_normal_deg"] = 30.0
    yield from random_views(n, seed, camera=camera, geometry=geometry, hazard=hazard,
                            **args)  # type: ignore[arg-type]
