"""Camera intrinsics: the pinhole + OpenCV distortion model, projection, and TOML files.

Intrinsics files are TOML with ``width``, ``height``, ``K`` (3 rows of 3, px), ``dist``
([k1, k2, p1, p2, k3]) and ``rms_px`` (DESIGN.md).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from pydantic import ValidationError

from schemas import CameraIntrinsics, describe_validation_error
from services.core.projection import normalise_px, project_px

#: The paper's web camera (eq. 3), 640 x 480.
PAPER_K = ((757.25, 2.06, 389.67), (0.0, 754.24, 260.5), (0.0, 0.0, 1.0))


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics K (3x3, px), distortion (k1, k2, p1, p2, k3) and image size (px)."""

    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    width: int = 640
    height: int = 480
    rms_px: float = 0.0

    def __post_init__(self) -> None:
        K = np.ascontiguousarray(self.K, dtype=np.float64)
        given = np.asarray(self.dist, dtype=np.float64).ravel()
        if K.shape != (3, 3):
            raise ValueError(f"K must be 3x3, got shape {K.shape}")
        if len(given) > 5 and np.any(given[5:]):
            raise ValueError(f"distortion has {len(given)} coefficients; this model takes "
                             "k1, k2, p1, p2, k3")
        dist = np.zeros(5)
        dist[:min(len(given), 5)] = given[:5]
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)

    def resized(self, width: int, height: int) -> CameraModel:
        """The same camera for images resized to ``width`` x ``height`` (pixel centres at
        +0.5: ``u' = (u + 0.5) sx - 0.5``); distortion is unchanged."""
        sx, sy = width / self.width, height / self.height
        K = self.K.copy()
        K[0, :2] *= sx
        K[1, 1] *= sy
        K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
        K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
        return CameraModel(K, self.dist.copy(), width, height, self.rms_px)

    @classmethod
    def pinhole(cls, f: float, cx: float, cy: float, width: int, height: int) -> CameraModel:
        """Square pixels, no skew or distortion: focal length ``f`` and principal point
        (``cx``, ``cy``), px."""
        return cls(np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]]), np.zeros(5),
                   width, height)

    @classmethod
    def paper(cls) -> CameraModel:
        return cls(np.array(PAPER_K, dtype=np.float64), np.zeros(5), 640, 480)

    @classmethod
    def from_message(cls, msg: CameraIntrinsics) -> CameraModel:
        return cls(np.array(msg.K, dtype=np.float64), np.array(msg.dist, dtype=np.float64),
                   msg.width, msg.height, msg.rms_px)

    def to_message(self) -> CameraIntrinsics:
        K = tuple(tuple(float(v) for v in row) for row in self.K)
        return CameraIntrinsics(width=self.width, height=self.height, K=K,  # type: ignore[arg-type]
                                dist=tuple(float(v) for v in self.dist),  # type: ignore[arg-type]
                                rms_px=self.rms_px)

    @classmethod
    def load(cls, path: str | Path) -> CameraModel:
        """Read an intrinsics TOML file; raises ValueError naming the file and the problem."""
        path = Path(path)
        try:
            data = tomllib.loads(path.read_text(encoding="utf-8"))
        except OSError as err:
            raise ValueError(f"{path}: cannot read intrinsics: {err.strerror}") from None
        except tomllib.TOMLDecodeError as err:
            raise ValueError(f"{path}: not valid TOML: {err}") from None
        fields = {k: data[k] for k in ("width", "height", "K", "dist", "rms_px") if k in data}
        try:
            return cls.from_message(CameraIntrinsics.model_validate(fields))
        except ValidationError as err:
            raise ValueError(f"{path}: {describe_validation_error(err)}") from None

    def to_toml(self, extra: str = "") -> str:
        rows = ",\n  ".join("[" + ", ".join(f"{v:.10g}" for v in row) + "]" for row in self.K)
        dist = ", ".join(f"{v:.10g}" for v in self.dist)
        return (f"width = {self.width}\nheight = {self.height}\nK = [\n  {rows},\n]\n"
                f"dist = [{dist}]  # k1, k2, p1, p2, k3 (OpenCV model)\n"
                f"rms_px = {self.rms_px:.6g}\n{extra}")

    def deskew_px(self, points_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels and a K without skew that OpenCV's skew-free model reads the same way."""
        K = self.K.copy()
        pts = np.array(points_px, dtype=np.float64).reshape(-1, 2)
        if K[0, 1] != 0.0:
            pts[:, 0] -= K[0, 1] * (pts[:, 1] - K[1, 2]) / K[1, 1]
            K[0, 1] = 0.0
        return pts, K

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Project points in the camera optical frame (N, 3) m to pixels (N, 2).

        Written out (pinhole with skew, radial k1 k2 k3, tangential p1 p2) in
        ``services/core/projection.py`` so that tests can check it against ``cv2.projectPoints``.
        """
        p = np.ascontiguousarray(np.asarray(points_cam, dtype=np.float64).reshape(-1, 3))
        return project_px(self.K, self.dist, p)


def undistort_px(camera: CameraModel, points_px: np.ndarray) -> np.ndarray:
    """Pixels -> ideal normalised image coordinates (N, 2), removing lens distortion."""
    pts = np.ascontiguousarray(points_px, np.float64).reshape(-1, 2)
    if not camera.dist.any():
        return normalise_px(camera.K, pts)
    deskewed, K = camera.deskew_px(pts)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)
    src = deskewed.reshape(-1, 1, 2)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x
        out = cv2.undistortPointsIter(src, K, camera.dist, None, None, criteria)
    else:  # OpenCV 5 folds the criteria into undistortPoints
        out = cv2.undistortPoints(src, K, camera.dist, None, None, None, criteria)
    return out.reshape(-1, 2)
