"""The marker's colour as the user's camera sees it: find the marker in sample images, fit a
``ColourModel`` (an ellipse in linear-light chromaticity, which does not depend on
brightness), say how well it separates marker from the rest, and read and write it as TOML.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from pydantic import ValidationError

from schemas import describe_validation_error
from services.vertex_extractor.colour import ColourModel

MIN_RECALL = 0.9         # share of the marker's interior the model must accept
MAX_FALSE = 0.002        # share of the rest of an image it may accept
MIN_MARKER_PX = 150      # a smaller found region is no marker
FLOOR_SIGMA = 0.02      # least chromaticity spread (noise a single image may not show)


class LearnError(ValueError):
    """The images do not give a usable model; the message says which and why."""


@dataclass(frozen=True)
class Separation:
    """How the model splits one image: marker interior accepted, rest accepted (fractions)."""

    name: str
    marker_px: int
    recall: float
    false_rate: float


def _linear(bgr: np.ndarray) -> np.ndarray:
    return ColourModel(transfer="srgb").lut[bgr] / 255.0


def _candidates(bgr: np.ndarray) -> np.ndarray:
    """Saturated magenta-family pixels (hue 260-355 deg in linear light), uint8 mask."""
    lin = _linear(bgr)
    b, g, r = lin[..., 0], lin[..., 1], lin[..., 2]
    hi = np.maximum(np.maximum(r, g), b)
    lo = np.minimum(np.minimum(r, g), b)
    sat = np.where(hi > 0, 1 - lo / np.maximum(hi, 1e-9), 0)
    hsv = cv2.cvtColor(np.clip(lin * 255, 0, 255).astype(np.uint8), cv2.COLOR_BGR2HSV_FULL)
    hue = hsv[..., 0].astype(float) * 360 / 256
    return ((sat > 0.6) & (hi > 0.06) & (hue >= 260) & (hue <= 355)).astype(np.uint8)


def find_marker(bgr: np.ndarray, roi: tuple[int, int, int, int] | None = None
                ) -> np.ndarray | None:
    """Mask (bool) of the marker: the largest convex four-cornered saturated blob (within
    ``roi`` x, y, w, h when given); None when there is none."""
    cand = _candidates(bgr)
    if roi is not None:
        x, y, w, h = roi
        keep = np.zeros_like(cand)
        keep[y:y + h, x:x + w] = 1
        cand &= keep
    _, labels, stats, _ = cv2.connectedComponentsWithStats(cand, connectivity=8)
    for k in np.argsort(stats[1:, cv2.CC_STAT_AREA])[::-1]:
        label = int(k) + 1
        if stats[label, cv2.CC_STAT_AREA] < MIN_MARKER_PX:
            break
        blob = (labels == label).astype(np.uint8)
        contours, _ = cv2.findContours(blob, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        c = max(contours, key=cv2.contourArea)
        quad = cv2.approxPolyDP(c, 0.04 * cv2.arcLength(c, True), True)
        hull_area = cv2.contourArea(cv2.convexHull(c))
        if len(quad) == 4 and cv2.isContourConvex(quad) and \
                cv2.contourArea(c) >= 0.85 * hull_area:
            return blob.astype(bool)
    return None


def _chroma(lin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = np.maximum(lin.sum(-1), 1e-9)
    return np.stack([lin[..., 2] / s, lin[..., 1] / s], -1), s


def learn(images: list[tuple[str, np.ndarray]], roi: tuple[int, int, int, int] | None = None,
          max_distance: float = 4.0) -> tuple[ColourModel, list[Separation]]:
    """Fit a model to the marker in each (name, BGR image); LearnError when the marker is
    not found in an image or the model cannot separate it from the rest of an image."""
    if not images:
        raise LearnError("no images given")
    masks = []
    samples = []
    sums = []
    for name, img in images:
        mask = find_marker(img, roi)
        if mask is None:
            where = f" within --roi {roi}" if roi else ""
            raise LearnError(f"{name}: no marker found{where} (a saturated, convex, "
                             f"four-cornered blob of at least {MIN_MARKER_PX} px)")
        inner = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
        if inner.sum() < 50:
            raise LearnError(f"{name}: the marker is too small to learn from "
                             f"({int(mask.sum())} px)")
        chroma, s = _chroma(_linear(img))
        masks.append((mask, inner))
        samples.append(chroma[inner])
        sums.append(s[inner])
    pts = np.concatenate(samples)
    centre = np.median(pts, 0)
    cov = np.cov(pts.T) + FLOOR_SIGMA ** 2 * np.eye(2)
    min_sum = float(min(0.05, 0.5 * np.percentile(np.concatenate(sums), 1)))
    model = ColourModel(centre=(float(centre[0]), float(centre[1])),
                        covariance=((float(cov[0, 0]), float(cov[0, 1])),
                                    (float(cov[1, 0]), float(cov[1, 1]))),
                        max_distance=max_distance, min_sum=min_sum)
    report = []
    for (name, img), (mask, inner) in zip(images, masks, strict=True):
        accepted = model.mask(img)
        rest = ~(cv2.dilate(mask.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0)
        sep = Separation(name, int(mask.sum()), float(accepted[inner].mean()),
                         float(accepted[rest].mean()) if rest.any() else 0.0)
        report.append(sep)
        if sep.recall < MIN_RECALL:
            raise LearnError(f"{name}: the model accepts only {100 * sep.recall:.0f}% of the "
                             f"marker (uneven light or a different ink in this image?)")
        if sep.false_rate > MAX_FALSE:
            raise LearnError(f"{name}: {100 * sep.false_rate:.2f}% of the rest of the image "
                             f"looks like the marker; the colour cannot be separated here "
                             "(try --roi, or a scene without marker-coloured things)")
    return model, report


def write_colour_file(path: Path, model: ColourModel, comment: str) -> None:
    """The model as a TOML file ``[colour]`` table (what ``colour_file`` reads)."""
    (a, b), (_, c) = model.covariance
    lines = [f"# {line}" for line in comment.splitlines()] + [
        "[colour]",
        f"centre = [{model.centre[0]:.5f}, {model.centre[1]:.5f}]   # linear-light (r, g)",
        f"covariance = [[{a:.6g}, {b:.6g}], [{b:.6g}, {c:.6g}]]",
        f"max_distance = {model.max_distance:g}",
        f"min_sum = {model.min_sum:.4f}",
        f'transfer = "{model.transfer}"',
    ]
    path.write_text("\n".join(lines) + "\n")


def load_colour_file(path: Path) -> ColourModel:
    """The ``[colour]`` table of a file written by ``shepherd marker learn``; ValueError
    naming the file and the field when it is not usable."""
    try:
        data = tomllib.loads(path.read_text())
    except OSError as err:
        raise ValueError(f"colour_file {path}: cannot read it ({err.strerror})") from None
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"colour_file {path}: not TOML ({err})") from None
    if not isinstance(data.get("colour"), dict):
        raise ValueError(f"colour_file {path}: no [colour] table")
    try:
        return ColourModel.model_validate(data["colour"])
    except ValidationError as err:
        raise ValueError(f"colour_file {path}: {describe_validation_error(err, 'colour')}"
                         ) from None
