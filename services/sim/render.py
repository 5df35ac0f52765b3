"""The simulated camera's view: the magenta rhombus on the humanoid's back, with clutter.

The rhombus is drawn with area-exact anti-aliasing up to 1/256 px² (16 x 16 supersampling over
its bounding box, then area averaging), through the camera's full distortion model (edges are
densely sampled before projection, so they bend as a real lens bends them). A render is
deterministic given its style's seed and the frame index.

Two cameras: the ideal one (a style without ``camera``, or ``camera.ideal``) draws in 8-bit
sRGB values (the marker's edge pixels mixed in linear light, as light mixes) and adds Gaussian
noise; the webcam (``webcam.py``) composes the scene in linear
light (photographed walls and floor when ``photos``, the humanoid's shaded plastic body, the
marker's ink) and passes it through the camera's stages.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import cv2
import numpy as np

from services.core.camera import CameraModel
from services.sim import hazards as hz
from services.sim import textures
from services.sim.webcam import WebcamParams, expose, linear_to_srgb, srgb_to_linear

MAGENTA_BGR = (255, 0, 255)
INKS_BGR = {  # the marker as printed (sRGB, BGR order)
    "nominal": MAGENTA_BGR,
    "process": (140, 0, 236),   # what a CMYK printer makes of "magenta" (0/100/0/0)
    "bluish": (206, 10, 180),   # a bluish-magenta card
}
BODY_BGR = (58, 62, 66)
SUPERSAMPLE = 16
SHIFT = 4  # fillPoly fractional bits inside the supersampled grid


@dataclass(frozen=True)
class RenderStyle:
    """How a frame looks: seed for the clutter, gain, noise (grey levels, 1-sigma), blur."""

    seed: int = 0
    brightness: float = 1.0
    noise_sigma: float = 2.0
    motion_blur_px: float = 0.0
    motion_blur_angle_deg: float = 0.0
    clutter: bool = True
    distractors: bool = True
    marker_bgr: tuple[int, int, int] = MAGENTA_BGR
    draw_body: bool = True
    background_level: int | None = None  # flat grey background instead of clutter
    camera: WebcamParams | None = None   # the webcam; None: the ideal camera
    photos: bool = False                 # webcam scenes: photographed walls and floor
    hazards: hz.Hazards | None = None    # webcam scenes: shadows, occluders, ... (hazards.py)


@dataclass(frozen=True)
class Rendered:
    """A rendered frame with its ground truth."""

    image: np.ndarray                 # H x W x 3 uint8 BGR
    vertices_px: np.ndarray | None    # (4, 2) left, top, right, bottom; None if not drawn
    T_camera_marker: np.ndarray       # 4x4
    marker_visible: bool              # drawn, facing the camera and wholly inside the image
    coverage_area_px: float           # rendered marker area (sum of coverage)
    occluded_fraction: float = 0.0    # share of the marker's area hidden by an occluder


@lru_cache(maxsize=8)
def _background(width: int, height: int, seed: int, clutter: bool, distractors: bool,
                level: int | None) -> np.ndarray:
    if level is not None:
        return np.full((height, width, 3), level, np.uint8)
    rng = np.random.default_rng(seed)
    img = np.empty((height, width, 3), np.uint8)
    horizon = int(height * rng.uniform(0.35, 0.55))
    wall = np.array([rng.uniform(170, 215), rng.uniform(175, 215), rng.uniform(170, 205)])
    floor = np.array([rng.uniform(80, 120), rng.uniform(105, 140), rng.uniform(130, 165)])
    ramp = np.linspace(0.85, 1.1, height)[:, None, None]
    img[:horizon] = np.clip(wall * ramp[:horizon], 0, 255).astype(np.uint8)
    img[horizon:] = np.clip(floor * ramp[horizon:], 0, 255).astype(np.uint8)
    if clutter:
        for _ in range(14):
            colour = _neutral_colour(rng)
            x, y = int(rng.uniform(0, width)), int(rng.uniform(0, height))
            w, h = int(rng.uniform(15, 120)), int(rng.uniform(10, 90))
            if rng.random() < 0.5:
                cv2.rectangle(img, (x, y), (x + w, y + h), colour, -1, cv2.LINE_AA)
            else:
                cv2.ellipse(img, (x, y), (w // 2, h // 2), float(rng.uniform(0, 180)), 0, 360,
                            colour, -1, cv2.LINE_AA)
        for _ in range(40):
            p1 = (int(rng.uniform(0, width)), int(rng.uniform(0, height)))
            p2 = (p1[0] + int(rng.normal(0, 60)), p1[1] + int(rng.normal(0, 60)))
            cv2.line(img, p1, p2, _neutral_colour(rng), 1, cv2.LINE_AA)
    if distractors:
        # Pinkish things a naive magenta test would take: hot pink, light pink, salmon, purple.
        pinks = [(180, 105, 255), (203, 192, 255), (147, 20, 255), (200, 80, 170),
                 (120, 110, 250)]
        for colour in pinks:
            x, y = int(rng.uniform(0, width)), int(rng.uniform(0, height))
            r = int(rng.uniform(8, 30))
            if rng.random() < 0.5:
                cv2.circle(img, (x, y), r, colour, -1, cv2.LINE_AA)
            else:
                cv2.rectangle(img, (x, y), (x + 2 * r, y + r), colour, -1, cv2.LINE_AA)
    img.setflags(write=False)
    return img


def _neutral_colour(rng: np.random.Generator) -> tuple[int, int, int]:
    while True:
        b, g, r = (int(v) for v in rng.integers(0, 256, 3))
        if not (g < 0.6 * min(r, b) and min(r, b) > 60):  # never marker-like
            return b, g, r


def _edge_samples(points_m: np.ndarray, per_edge: int) -> np.ndarray:
    """Closed polygon boundary sampled densely (so distortion bends its edges)."""
    a, b = points_m, np.roll(points_m, -1, axis=0)
    t = np.linspace(0.0, 1.0, per_edge, endpoint=False)[None, :, None]
    return (a[:, None, :] * (1 - t) + b[:, None, :] * t).reshape(-1, 3)


def coverage_mask(polygon_px: np.ndarray, x0: int, y0: int, w: int, h: int,
                  supersample: int = SUPERSAMPLE) -> np.ndarray:
    """Fraction of each pixel of the box (x0, y0, w, h) covered by a polygon (float32 0..1),
    to 1 / supersample² px².

    Pixel (i, j) covers [j - 0.5, j + 0.5] x [i - 0.5, i + 0.5] (pixel centres at integers).
    """
    s = supersample
    canvas = np.zeros((h * s, w * s), np.uint8)
    # supersampled coordinate of a point: (x - x0 + 0.5) * s, minus half a subpixel because
    # fillPoly samples at subpixel centres.
    sub = ((polygon_px - [x0 - 0.5, y0 - 0.5]) * s - 0.5) * (1 << SHIFT)
    cv2.fillPoly(canvas, [np.round(sub).astype(np.int32)], 1, cv2.LINE_8, SHIFT)
    return cv2.resize(canvas.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)


def _body_corners(T_camera_humanoid: np.ndarray) -> list[np.ndarray]:
    boxes = [((-0.045, 0.045), (-0.08, 0.08), (0.06, 0.34)),   # torso and head
             ((-0.03, 0.03), (-0.07, 0.07), (0.0, 0.06))]       # legs
    out = []
    for (x0, x1), (y0, y1), (z0, z1) in boxes:
        c = np.array([[x, y, z, 1.0] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)])
        out.append((T_camera_humanoid @ c.T).T[:, :3])
    return out


def render_view(camera: CameraModel, T_camera_marker: np.ndarray, *,
                marker_points_m: np.ndarray,
                T_camera_humanoid: np.ndarray | None = None,
                style: RenderStyle | None = None, frame_index: int = 0,
                draw_marker: bool = True) -> Rendered:
    """Render one frame.

    Args:
        camera: intrinsics, distortion and size.
        T_camera_marker: marker frame -> camera optical frame, 4x4 (m).
        marker_points_m: (4, 3) rhombus vertices in the marker frame, left, top, right, bottom.
        T_camera_humanoid: humanoid frame -> camera, to draw its body (optional).
        style: look of the frame; ``frame_index`` varies the noise deterministically.
    """
    style = style or RenderStyle()
    if style.camera is not None and not style.camera.ideal:
        return _render_webcam(camera, T_camera_marker, marker_points_m, T_camera_humanoid, style,
                              frame_index, draw_marker)
    W, H = camera.width, camera.height
    img = _background(W, H, style.seed, style.clutter, style.distractors,
                      style.background_level).astype(np.float32)
    if style.draw_body and T_camera_humanoid is not None:
        _draw_body(img, camera, T_camera_humanoid, np.array(BODY_BGR, np.float32), False)
    vertices_px, facing, area = _draw_marker(img, camera, T_camera_marker, marker_points_m,
                                             np.array(style.marker_bgr, np.float32),
                                             draw_marker, srgb=True)
    if style.brightness != 1.0:
        img *= style.brightness
    if style.motion_blur_px > 0.5:
        img = cv2.filter2D(img, -1, _blur_kernel(style.motion_blur_px,
                                                 style.motion_blur_angle_deg))
    if style.noise_sigma > 0:
        noise = np.empty((H, W, 3), np.float32)
        cv2.setRNGSeed(style.seed * 1_000_003 + frame_index)
        cv2.randn(noise, 0.0, style.noise_sigma)
        img += noise
    image = np.clip(img + 0.5, 0, 255).astype(np.uint8)
    return _rendered(image, vertices_px, T_camera_marker, facing, draw_marker, area)


def _rendered(image: np.ndarray, vertices_px: np.ndarray | None, T_camera_marker: np.ndarray,
              facing: bool, draw_marker: bool, area: float) -> Rendered:
    H, W = image.shape[:2]
    visible = (facing and vertices_px is not None and draw_marker
               and bool(np.all((vertices_px >= 0) & (vertices_px <= [W - 1, H - 1]))))
    return Rendered(image, vertices_px, T_camera_marker, visible, area)


def _draw_marker(img: np.ndarray, camera: CameraModel, T_camera_marker: np.ndarray,
                 marker_points_m: np.ndarray, colour: np.ndarray, draw: bool,
                 srgb: bool = False, supersample: int = SUPERSAMPLE
                 ) -> tuple[np.ndarray | None, bool, float]:
    """Composite the rhombus into ``img`` (float32, in place) by its exact pixel coverage, in
    linear light (``srgb``: ``img`` and ``colour`` hold sRGB values 0-255, converted for the
    mix and back). Returns (true vertices px or None, facing the camera, drawn area px)."""
    H, W = img.shape[:2]
    verts_cam = (T_camera_marker[:3, :3] @ marker_points_m.T).T + T_camera_marker[:3, 3]
    normal = T_camera_marker[:3, 2]
    in_front = bool(np.all(verts_cam[:, 2] > 0.01))
    facing = float(normal @ T_camera_marker[:3, 3]) < 0 and in_front
    vertices_px = camera.project(verts_cam) if in_front else None
    area = 0.0
    if draw and facing and vertices_px is not None:
        boundary = camera.project(_edge_samples(verts_cam, 48))
        lo = np.floor(boundary.min(0) - 1).astype(int)
        hi = np.ceil(boundary.max(0) + 1).astype(int)
        x0, y0 = max(lo[0], 0), max(lo[1], 0)
        x1, y1 = min(hi[0], W - 1), min(hi[1], H - 1)
        if x1 > x0 and y1 > y0:
            cov = coverage_mask(boundary, x0, y0, x1 - x0 + 1, y1 - y0 + 1,
                                supersample)[..., None]
            roi = img[y0:y1 + 1, x0:x1 + 1]
            if srgb:
                mixed = (srgb_to_linear(roi / 255.0) * (1.0 - cov)
                         + cov * srgb_to_linear(colour / 255.0))
                roi[...] = 255.0 * linear_to_srgb(mixed)
            else:
                roi *= 1.0 - cov
                roi += cov * colour
            area = float(cov.sum())
    return vertices_px, facing, area


def _draw_body(img: np.ndarray, camera: CameraModel, T_camera_humanoid: np.ndarray,
               colour: np.ndarray, shaded: bool) -> None:
    """The humanoid's torso and legs as boxes (float32 image, in place); ``shaded``: plastic
    lit from above (brighter at the top, a highlight band)."""
    for corners in _body_corners(T_camera_humanoid):
        if not np.all(corners[:, 2] > 0.02):
            continue
        hull = cv2.convexHull(camera.project(corners).astype(np.float32))
        if not shaded:
            cv2.fillConvexPoly(img, np.round(hull * 16).astype(np.int32), colour.tolist(),
                               cv2.LINE_AA, 4)
            continue
        x, y, w, h = cv2.boundingRect(np.round(hull).astype(np.int32))
        x0, y0 = max(x - 1, 0), max(y - 1, 0)
        x1, y1 = min(x + w + 1, img.shape[1]), min(y + h + 1, img.shape[0])
        if x1 <= x0 or y1 <= y0:
            continue
        cov = np.zeros((y1 - y0, x1 - x0), np.float32)
        cv2.fillConvexPoly(cov, np.round((hull.reshape(-1, 2) - [x0, y0]) * 16).astype(np.int32),
                           1.0, cv2.LINE_AA, 4)
        cov = cov[..., None]
        t = np.linspace(0.0, 1.0, y1 - y0, dtype=np.float32)
        u = np.linspace(-1.0, 1.0, x1 - x0, dtype=np.float32)
        shade = (np.outer(1.25 - 0.5 * t, 1.0 - 0.25 * u * u)
                 + 0.35 * np.exp(-((u - 0.3) / 0.15) ** 2)[None, :])
        roi = img[y0:y1, x0:x1]
        roi *= 1.0 - cov
        roi += (cov * shade[..., None]) * colour


def _render_webcam(camera: CameraModel, T_camera_marker: np.ndarray,
                   marker_points_m: np.ndarray, T_camera_humanoid: np.ndarray | None,
                   style: RenderStyle, frame_index: int, draw_marker: bool) -> Rendered:
    """The scene in linear light through the webcam (``style.camera``)."""
    assert style.camera is not None
    W, H = camera.width, camera.height
    if style.photos:
        img = textures.photo_scene(W, H, style.seed).copy()
    else:
        bg = _background(W, H, style.seed, style.clutter, style.distractors,
                         style.background_level)
        img = srgb_to_linear(bg / 255.0).astype(np.float32)
    if style.draw_body and T_camera_humanoid is not None:
        _draw_body(img, camera, T_camera_humanoid,
                   srgb_to_linear(np.array(BODY_BGR) / 255.0).astype(np.float32), True)
    ink = srgb_to_linear(np.array(style.marker_bgr) / 255.0).astype(np.float32)
    h = style.hazards
    if h is not None and h.distractors:
        in_front = (T_camera_marker[:3, :3] @ marker_points_m.T).T + T_camera_marker[:3, 3]
        avoid = camera.project(in_front) if draw_marker and np.all(in_front[:, 2] > 0.01) \
            else None
        span = np.ptp(marker_points_m[:, :2], axis=0)  # the diagonals (x, y), m
        hz.draw_distractors(img, h, avoid, float(span[0] / max(span[1], 1e-9)))
    vertices_px, facing, area = _draw_marker(img, camera, T_camera_marker, marker_points_m, ink,
                                             draw_marker)
    hidden = 0.0
    if h is not None and vertices_px is not None and draw_marker and facing:
        cov = hz.poly_coverage(vertices_px, (H, W)) if h.occluder != "none" else None
        hidden = hz.apply_foreground(img, h, vertices_px, cov)
    img *= style.brightness
    if style.motion_blur_px > 0.5:
        img = cv2.filter2D(img, -1, _blur_kernel(style.motion_blur_px,
                                                 style.motion_blur_angle_deg))
    if h is not None:
        img, vertices_px = hz.apply_optics(img, h, vertices_px)
    rng = np.random.default_rng([style.seed, frame_index])
    image = expose(img, style.camera, rng)
    out = _rendered(image, vertices_px, T_camera_marker, facing, draw_marker, area)
    return replace(out, occluded_fraction=hidden) if hidden else out


@lru_cache(maxsize=16)
def _blur_kernel(length: float, angle_deg: float) -> np.ndarray:
    n = int(np.ceil(length)) | 1
    k = np.zeros((n, n), np.float32)
    c = n // 2
    d = np.array([np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))])
    for t in np.linspace(-length / 2, length / 2, 4 * n):
        x, y = c + t * d
        k[round(y), round(x)] += 1.0
    return k / k.sum()
