"""What a real room does to the marker: cast shadows, an arm or a bar in front of it, a glossy
print's highlight, pink and magenta things in view, defocus and a rolling shutter (the
``[services.sim.hazards]`` table; ``RenderStyle.hazards``).

Each hazard is off by default and switched on by its own parameters. They act on the webcam
path's linear-light scene (``render._render_webcam``), after the marker is drawn, in the order
light meets them: distractors in the room, the marker, an occluder in front of it, the print's
specular highlight, the cast shadow over everything, motion blur (``RenderStyle``), defocus, and
the rolling shutter (a shear of the frame; the truth vertices are sheared with it).

Positions that follow the marker are given in its own image frame: ``(a, b)`` is the point
``centre + a (right - left) / 2 + b (bottom - top) / 2`` of its projected vertices, so that
``(±1, 0)`` and ``(0, ±1)`` are its vertices whatever the view.
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

DistractorKind = Literal["card", "shirt", "cup", "rhombus"]
SKIN_LINEAR_BGR = (0.30, 0.38, 0.62)      # a hand or an arm, lit
BAR_LINEAR_BGR = (0.05, 0.05, 0.055)      # the humanoid's dark plastic arm


class Hazards(BaseModel):
    """The hazards of one frame (each off by default)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    shadow_factor: float = Field(default=1.0, gt=0.0, le=1.0,
                                 description="light left in the cast shadow (1: no shadow)")
    shadow_softness_px: float = Field(default=0.0, ge=0.0, le=200.0,
                                      description="width of the penumbra (0: hard edge)")
    shadow_angle_deg: float = Field(default=0.0, description="direction of the shadow's edge")
    shadow_offset: float = Field(default=0.0, ge=-1.5, le=1.5,
                                 description="the shadow edge's distance from the marker "
                                             "centre, in half-diagonals")
    occluder: Literal["none", "limb", "bar"] = Field(
        default="none", description="a limb (skin, round ends) or a bar (dark plastic) in front "
        "of the marker")
    occluder_from: tuple[float, float] = Field(
        default=(1.6, -1.2), description="where the occluder comes from (marker frame)")
    occluder_to: tuple[float, float] = Field(
        default=(0.7, -0.5), description="where it ends (marker frame): inside the marker")
    occluder_width: float = Field(default=0.25, gt=0.0, le=2.0,
                                  description="thickness, in vertical half-diagonals")
    specular_gain: float = Field(default=0.0, ge=0.0, le=20.0,
                                 description="peak of the print's highlight, x white light")
    specular_at: tuple[float, float] = Field(
        default=(0.3, -0.3), description="the highlight's centre (marker frame)")
    specular_radius: float = Field(default=0.3, gt=0.0, le=3.0,
                                   description="1/e radius, in vertical half-diagonals")
    distractors: tuple[DistractorKind, ...] = Field(
        default=(), description="magenta things in the room: cards, shirts, cups, rhombi")
    distractor_seed: int = Field(default=0, description="where the distractors stand")
    defocus_px: float = Field(default=0.0, ge=0.0, le=12.0, description="blur disc radius")
    rolling_shutter_px: float = Field(
        default=0.0, ge=-80.0, le=80.0,
        description="horizontal motion during readout: the bottom row is this much right of "
                    "the top row")

    @property
    def any(self) -> bool:
        return self != Hazards()


def marker_frame_point(vertices_px: np.ndarray, a: float, b: float) -> np.ndarray:
    """The image point (a, b) of the marker's own frame (see the module docstring)."""
    c = vertices_px.mean(0)
    return c + a * (vertices_px[2] - vertices_px[0]) / 2 + b * (vertices_px[3] - vertices_px[1]) / 2


def _half_height(vertices_px: np.ndarray) -> float:
    return float(np.linalg.norm(vertices_px[3] - vertices_px[1]) / 2)


def occluder_mask(h: Hazards, vertices_px: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Coverage (float32 0..1, H x W) of the occluder: a capsule (limb: round ends) or a
    straight-ended strip (bar) from ``occluder_from`` to ``occluder_to``."""
    H, W = shape
    mask = np.zeros((H * 4, W * 4), np.uint8)
    p = marker_frame_point(vertices_px, *h.occluder_from)
    q = marker_frame_point(vertices_px, *h.occluder_to)
    width = h.occluder_width * _half_height(vertices_px)
    if h.occluder == "limb":
        cv2.line(mask, tuple(int(v) for v in np.round(p * 4 + 1.5)),
                 tuple(int(v) for v in np.round(q * 4 + 1.5)), 255,
                 max(round(width * 4), 1), cv2.LINE_8)
        for end in (p, q):
            cv2.circle(mask, tuple(int(v) for v in np.round(end * 4 + 1.5)),
                       max(round(width * 2), 1), 255, -1, cv2.LINE_8)
    else:
        d = q - p
        n = np.array([-d[1], d[0]]) / max(float(np.linalg.norm(d)), 1e-9) * width / 2
        poly = np.array([p + n, q + n, q - n, p - n])
        cv2.fillPoly(mask, [np.round(poly * 4 + 1.5).astype(np.int32)], 255, cv2.LINE_8)
    return cv2.resize(mask.astype(np.float32) / 255.0, (W, H), interpolation=cv2.INTER_AREA)


def apply_foreground(img: np.ndarray, h: Hazards, vertices_px: np.ndarray,
                     marker_cov: np.ndarray | None) -> float:
    """Occluder, highlight and shadow on the linear scene ``img`` (in place), given the
    marker's true vertices. Returns the share of the marker's area the occluder hides."""
    H, W = img.shape[:2]
    hidden = 0.0
    if h.occluder != "none":
        cov = occluder_mask(h, vertices_px, (H, W))
        colour = np.array(SKIN_LINEAR_BGR if h.occluder == "limb" else BAR_LINEAR_BGR,
                          np.float32)
        # shaded across its width: brighter in the middle (a rounded limb)
        img *= 1.0 - cov[..., None]
        img += cov[..., None] * colour
        if marker_cov is not None and marker_cov.sum() > 0:
            hidden = float((marker_cov * cov).sum() / marker_cov.sum())
    if h.specular_gain > 0:
        c = marker_frame_point(vertices_px, *h.specular_at)
        r = h.specular_radius * _half_height(vertices_px)
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
        blob = h.specular_gain * np.exp(-((xx - c[0]) ** 2 + (yy - c[1]) ** 2) / (r * r))
        img += blob[..., None]
    if h.shadow_factor < 1.0:
        c = vertices_px.mean(0)
        a = np.radians(h.shadow_angle_deg)
        n = np.array([np.cos(a), np.sin(a)])
        side = _half_height(vertices_px)
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
        dist = (xx - c[0]) * n[0] + (yy - c[1]) * n[1] - h.shadow_offset * side
        if h.shadow_softness_px > 0:
            t = np.clip(0.5 + dist / h.shadow_softness_px, 0.0, 1.0)
            t = t * t * (3 - 2 * t)
        else:  # hard: area-exact across the edge pixel
            t = np.clip(0.5 + dist, 0.0, 1.0)
        img *= (1.0 - (1.0 - h.shadow_factor) * t)[..., None]
    return hidden


#: an 8-bit channel at or above this has clipped (sRGB; the extractor's ``HALO_CLIPPED``)
CLIPPED_LEVEL = 250
CLIPPED_INSET_PX = 2.5  # how far inside each edge its ink is read: past the blur's ramp


def clipped_edge_share(image: np.ndarray, vertices_px: np.ndarray, samples: int = 40
                       ) -> np.ndarray:
    """Per edge (left-top, top-right, right-bottom, bottom-left), the share of its length
    (``samples`` points over its middle 90 %) along which the marker's ink clips in some
    channel ``CLIPPED_INSET_PX`` px inside it: a glossy print's highlight. There the edge
    cannot be measured without bias (clipping after the blur moves the half-way crossing by
    the unknown overexposure) and the extractor leaves its points out; a line needs half an
    edge's points, so an edge clipped over half its length is as hidden as one under an arm.
    ``image``: the frame (H, W, 3) uint8; ``vertices_px`` (4, 2) its true vertices."""
    H, W = image.shape[:2]
    v = np.asarray(vertices_px, np.float64)
    centre = v.mean(axis=0)
    t = np.linspace(0.05, 0.95, samples)[:, None]
    share = np.zeros(4)
    for k in range(4):
        p, q = v[k], v[(k + 1) % 4]
        normal = np.array([q[1] - p[1], p[0] - q[0]]) / max(float(np.linalg.norm(q - p)), 1e-9)
        if normal @ (0.5 * (p + q) - centre) > 0:
            normal = -normal  # inward
        at = np.rint(p + t * (q - p) + CLIPPED_INSET_PX * normal).astype(np.int64)
        x, y = np.clip(at[:, 0], 0, W - 1), np.clip(at[:, 1], 0, H - 1)
        share[k] = float(np.mean(image[y, x].max(axis=1) >= CLIPPED_LEVEL))
    return share


def apply_optics(img: np.ndarray, h: Hazards, vertices_px: np.ndarray | None
                 ) -> tuple[np.ndarray, np.ndarray | None]:
    """Defocus and rolling shutter on the linear scene; returns it and the moved vertices."""
    if h.defocus_px > 0.3:
        r = h.defocus_px
        n = int(np.ceil(r)) * 2 + 1
        yy, xx = np.mgrid[0:n * 8, 0:n * 8].astype(np.float32)
        c = n * 4 - 0.5
        disc = ((xx - c) ** 2 + (yy - c) ** 2 <= (8 * r) ** 2).astype(np.float32)
        k = cv2.resize(disc, (n, n), interpolation=cv2.INTER_AREA)
        img = cv2.filter2D(img, -1, k / k.sum(), borderType=cv2.BORDER_REFLECT)
    if h.rolling_shutter_px != 0:
        H, W = img.shape[:2]
        s = h.rolling_shutter_px / max(H - 1, 1)
        M = np.array([[1.0, s, 0.0], [0.0, 1.0, 0.0]], np.float32)  # x' = x + s y
        img = cv2.warpAffine(img, M, (W, H), flags=cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_REFLECT)
        if vertices_px is not None:
            vertices_px = vertices_px + np.column_stack([s * vertices_px[:, 1],
                                                         np.zeros(len(vertices_px))])
    return img, vertices_px


MAGENTA_INKS_LINEAR_BGR = ((1.0, 0.0, 1.0), (0.26, 0.0, 0.83), (0.62, 0.003, 0.46))


def poly_coverage(poly_px: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    H, W = shape
    mask = np.zeros((H * 4, W * 4), np.uint8)
    cv2.fillPoly(mask, [np.round(poly_px * 4 + 1.5).astype(np.int32)], 255, cv2.LINE_8)
    return cv2.resize(mask.astype(np.float32) / 255.0, (W, H), interpolation=cv2.INTER_AREA)


def _rotated(points: np.ndarray, angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return points @ np.array([[c, s], [-s, c]])


#: the other rhombus (``distractors``) is another shape than the marker: 1.0-1.6 times as
#: wide as tall beside a marker at most 1 / 1.3 as wide as tall (the default is 0.76), else
#: this many times the marker's own width over height
OTHER_RHOMBUS = (1.3, 2.1)


def _distractor_shape(kind: str, rng: np.random.Generator, marker_ratio: float
                      ) -> list[np.ndarray]:
    """Polygons (px, about the origin) of one distractor; ``marker_ratio``: the marker's
    horizontal diagonal over its vertical one."""
    if kind == "card":  # a credit card or a postcard, any in-plane angle, some perspective
        w = rng.uniform(30, 160)
        h = w / rng.choice([1.586, 1.414, 1.5])
        quad = np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) / 2
        quad = quad * (1 + rng.uniform(-0.12, 0.12, (4, 1)))  # perspective, roughly
        return [_rotated(quad, rng.uniform(0, np.pi))]
    if kind == "rhombus":  # another shape: wider than the marker (``OTHER_RHOMBUS``)
        v = rng.uniform(30, 140)
        low, high = OTHER_RHOMBUS
        ratio = rng.uniform(1.0, 1.6) if marker_ratio * low <= 1.0 else \
            rng.uniform(marker_ratio * low, marker_ratio * high)
        quad = np.array([[-ratio * v, 0], [0, -v], [ratio * v, 0], [0, v]]) / 2
        return [_rotated(quad, np.radians(rng.uniform(-15, 15)))]
    if kind == "cup":  # a body with an elliptic rim and base
        w, h = rng.uniform(25, 80), rng.uniform(35, 110)
        t = np.linspace(0, np.pi, 24)
        rim = np.column_stack([w / 2 * np.cos(t), -h / 2 - 0.15 * w * np.sin(t)])
        base = np.column_stack([-w / 2 * np.cos(t), h / 2 + 0.15 * w * np.sin(t)])
        return [np.vstack([rim, base])]
    # a shirt: a torso with sleeves, held at an angle
    s = rng.uniform(60, 220)
    shirt = np.array([[-0.3, -0.5], [-0.12, -0.55], [0.12, -0.55], [0.3, -0.5], [0.55, -0.2],
                      [0.42, -0.05], [0.3, -0.2], [0.3, 0.5], [-0.3, 0.5], [-0.3, -0.2],
                      [-0.42, -0.05], [-0.55, -0.2]]) * s
    return [_rotated(shirt, np.radians(rng.uniform(-25, 25)))]


def draw_distractors(img: np.ndarray, h: Hazards, avoid_px: np.ndarray | None,
                     marker_ratio: float) -> None:
    """Magenta things in the room (linear scene, in place), kept clear of ``avoid_px`` (the
    marker's vertices) by a margin; none of them the marker's shape (``marker_ratio``: its
    horizontal diagonal over its vertical one)."""
    H, W = img.shape[:2]
    rng = np.random.default_rng(h.distractor_seed)
    if avoid_px is not None:
        lo, hi = avoid_px.min(0) - 12, avoid_px.max(0) + 12
    for kind in h.distractors:
        polys = _distractor_shape(kind, rng, marker_ratio)
        ext = np.vstack(polys)
        span = ext.max(0) - ext.min(0)
        for _ in range(40):  # somewhere in the frame, not over the marker
            c = rng.uniform([0.05 * W, 0.05 * H], [0.95 * W, 0.95 * H])
            a, b = ext.min(0) + c, ext.max(0) + c
            if avoid_px is None or np.any(b < lo) or np.any(a > hi):
                break
        else:
            continue
        cov = np.zeros((H, W), np.float32)
        for poly in polys:
            cov = np.maximum(cov, poly_coverage(poly + c, (H, W)))
        ink = np.array(MAGENTA_INKS_LINEAR_BGR[int(rng.integers(len(MAGENTA_INKS_LINEAR_BGR)))],
                       np.float32) * rng.uniform(0.5, 1.0)
        # folds and shading: slow brightness changes across the object
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
        k = 2 * np.pi / max(float(span.max()), 1.0) * rng.uniform(0.5, 2.0)
        shade = 0.8 + 0.2 * np.sin(k * (xx * 0.8 + yy * 0.6) + rng.uniform(0, 6.3))
        img *= 1.0 - cov[..., None]
        img += (cov * shade)[..., None] * ink
