"""Calibrate a camera from image files: detect, skip failures, Zhang, write the results."""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from services.calibration.detect import DetectionError, detect
from services.calibration.pattern import PatternSpec
from services.calibration.zhang import Calibration, CalibrationError, calibrate
from services.core.camera import CameraModel


@dataclass(frozen=True)
class ViewResult:
    path: Path
    points_px: np.ndarray | None
    error: str = ""


def read_image(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:  # e.g. GIF, which imread may not read
        cap = cv2.VideoCapture(str(path))
        ok, frame = cap.read()
        cap.release()
        if not ok:
            raise DetectionError(f"cannot read image {path}")
        image = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    return image


def detect_views(paths: list[Path], spec: PatternSpec, log=print) -> tuple[list[ViewResult],
                                                                         tuple[int, int]]:
    """Detect the pattern in every image; a view where it is not found is kept with its
    reason. Returns the views and the image size (width, height)."""
    views, size = [], None
    for i, path in enumerate(paths, 1):
        try:
            image = read_image(path)
            if size is None:
                size = (image.shape[1], image.shape[0])
            elif size != (image.shape[1], image.shape[0]):
                raise DetectionError(f"image is {image.shape[1]}x{image.shape[0]}, the first "
                                     f"was {size[0]}x{size[1]}")
            pts = detect(image, spec)
            views.append(ViewResult(path, pts))
            log(f"[{i}/{len(paths)}] {path.name}: {len(pts)} points")
        except DetectionError as err:
            views.append(ViewResult(path, None, str(err)))
            log(f"[{i}/{len(paths)}] {path.name}: skipped ({err})")
    return views, size or (0, 0)


def run(paths: list[Path], spec: PatternSpec, *, skew: bool = True, log=print
        ) -> tuple[Calibration, list[ViewResult], tuple[int, int]]:
    """Raises CalibrationError when fewer than three views are usable."""
    views, size = detect_views(paths, spec, log)
    good = [v for v in views if v.points_px is not None]
    if len(good) < 3:
        raise CalibrationError(f"only {len(good)} of {len(views)} views usable; need at "
                               "least 3")
    model = spec.model_points()
    points = [v.points_px for v in good if v.points_px is not None]
    return calibrate([model] * len(points), points, skew=skew), views, size


def to_toml(cal: Calibration, size: tuple[int, int], views: list[ViewResult],
            spec_text: str) -> str:
    cam = CameraModel(cal.K, cal.dist, size[0], size[1], cal.rms_px)
    good = [v for v in views if v.points_px is not None]
    extra = [f'\n[calibration]\npattern = "{spec_text}"',
             f"views_used = {len(good)}", f"views_skipped = {len(views) - len(good)}",
             "per_view_rms_px = [" + ", ".join(f"{r:.4f}" for r in cal.per_view_rms_px) + "]",
             "view_files = [" + ", ".join(f'"{v.path.name}"' for v in good) + "]",
             "\n[calibration.std]  # 1-sigma of the estimates"]
    extra += [f"{k} = {v:.6g}" for k, v in cal.std.items()]
    return cam.to_toml("\n".join(extra) + "\n")


def write_opencv_yaml(cal: Calibration, size: tuple[int, int], path: Path) -> None:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", size[0])
    fs.write("image_height", size[1])
    fs.write("camera_matrix", cal.K)
    fs.write("distortion_coefficients", cal.dist.reshape(1, 5))
    fs.write("rms_px", cal.rms_px)
    fs.release()


def residual_plot(path: Path, image_path: Path, points: np.ndarray, residuals: np.ndarray,
                  scale: float = 20.0) -> None:
    """The image with detected points (green) and residual vectors x ``scale`` (red)."""
    img = cv2.cvtColor(read_image(image_path), cv2.COLOR_GRAY2BGR)
    for p, r in zip(points, residuals, strict=True):
        a = tuple(np.round(p).astype(int).tolist())
        b = tuple(np.round(p + scale * r).astype(int).tolist())
        cv2.circle(img, a, 3, (0, 200, 0), 1, cv2.LINE_AA)
        cv2.line(img, a, b, (0, 0, 255), 1, cv2.LINE_AA)
    rms = float(np.sqrt(np.mean(np.sum(residuals ** 2, axis=1))))
    cv2.putText(img, f"{image_path.name}: RMS {rms:.3f} px (residuals x{scale:g})", (10, 22),
                cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 255), 1, cv2.LINE_AA)
    cv2.imwrite(str(path), img)


def report(cal: Calibration) -> str:
    K, s = cal.K, cal.std
    def pm(name: str) -> str:
        return f" ± {s[name]:.3g}" if name in s else ""
    return "\n".join([
        f"  alpha (fx)  {K[0, 0]:10.3f}{pm('alpha')} px",
        f"  beta (fy)   {K[1, 1]:10.3f}{pm('beta')} px",
        f"  gamma       {K[0, 1]:10.4f}{pm('gamma')} px",
        f"  u0, v0      {K[0, 2]:10.3f}{pm('u0')}, {K[1, 2]:.3f}{pm('v0')} px",
        f"  k1, k2      {cal.dist[0]:10.5f}{pm('k1')}, {cal.dist[1]:.5f}{pm('k2')}",
        f"  RMS         {cal.rms_px:10.4f} px over {len(cal.per_view_rms_px)} views "
        f"(per view: {', '.join(f'{r:.3f}' for r in cal.per_view_rms_px)})",
        f"  field of view {math.degrees(2 * math.atan(K[0, 2] / K[0, 0])):.1f}° wide"])


def main(paths: list[Path], spec_text: str, out: Path, plots: Path | None, skew: bool) -> int:
    try:
        spec = PatternSpec.parse(spec_text)
    except ValueError as err:
        print(f"shepherd: {err}", file=sys.stderr)
        return 2
    missing = [p for p in paths if not p.is_file()]
    if missing:
        print(f"shepherd: no such image: {missing[0]}", file=sys.stderr)
        return 2
    try:
        cal, views, size = run(paths, spec, skew=skew)
    except CalibrationError as err:
        print(f"shepherd: calibration failed: {err}", file=sys.stderr)
        return 2
    out.write_text(to_toml(cal, size, views, spec_text))
    yaml = out.with_suffix(".yaml")
    write_opencv_yaml(cal, size, yaml)
    print(f"\nCalibration from {len(cal.per_view_rms_px)} views ({size[0]}x{size[1]}):")
    print(report(cal))
    print(f"wrote {out} and {yaml} (OpenCV)")
    if plots is not None:
        plots.mkdir(parents=True, exist_ok=True)
        good = [v for v in views if v.points_px is not None]
        for v, r in zip(good, cal.residuals_px, strict=True):
            assert v.points_px is not None
            residual_plot(plots / f"{v.path.stem}_residuals.png", v.path, v.points_px, r)
        print(f"wrote {len(good)} residual plots to {plots}")
    return 0
