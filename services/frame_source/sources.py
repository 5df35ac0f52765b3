"""Where frames come from: anything cv2.VideoCapture opens, or an image folder / glob.

Each frame carries the time it was taken (Unix ns) and which clock said so:
- ``grab``: a live camera or stream; the time just before ``grab()`` (the driver's buffer is
  kept to one frame, so a grabbed frame is not an old one);
- ``container``: a video file; its own timestamps (``CAP_PROP_POS_MSEC``), counted from the
  moment playback started (again from each loop's start), so frames are as far apart as the
  file says, whatever pace they are read at;
- ``read``: image files have no time; the moment each was read.
"""

from __future__ import annotations

import glob
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".gif", ".webp"}
StampSource = Literal["grab", "container", "read"]


class SourceEndedError(Exception):
    """The source has no more frames (a file or folder that ended, not looping)."""


class SourceLostError(Exception):
    """The source failed (device unplugged, stream dropped); it may come back."""


@dataclass(frozen=True)
class Grabbed:
    """One frame: BGR pixels, when it was taken (Unix ns), and which clock said so."""

    image: np.ndarray
    stamp_ns: int
    stamp_source: StampSource


class ImageFiles:
    """Images from a folder or a glob pattern, in name order, looped or once."""

    stamp_source: StampSource = "read"

    def __init__(self, spec: str, loop: bool = True) -> None:
        self.controls: dict[str, float] = {}  # files have no camera controls
        self.refused: list[str] = []
        path = Path(spec)
        if path.is_dir():
            files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        else:
            files = sorted(Path(p) for p in glob.glob(spec)
                           if Path(p).suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise SourceLostError(f"no images match {spec!r}")
        self.files, self.loop, self._i = files, loop, 0
        self.description = f"{len(files)} images from {spec}"

    def read(self) -> Grabbed:
        if self._i >= len(self.files):
            if not self.loop:
                raise SourceEndedError(f"all {len(self.files)} images sent")
            self._i = 0
        path = self.files[self._i]
        self._i += 1
        stamp = time.time_ns()
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise SourceLostError(f"cannot decode image {path}")
        return Grabbed(image, stamp, "read")

    def close(self) -> None:
        pass


#: Camera controls a deployment may set: name -> OpenCV property.
CONTROLS = {
    "width": cv2.CAP_PROP_FRAME_WIDTH, "height": cv2.CAP_PROP_FRAME_HEIGHT,
    "fps": cv2.CAP_PROP_FPS, "fourcc": cv2.CAP_PROP_FOURCC,
    "auto_exposure": cv2.CAP_PROP_AUTO_EXPOSURE, "exposure": cv2.CAP_PROP_EXPOSURE,
    "auto_white_balance": cv2.CAP_PROP_AUTO_WB, "white_balance": cv2.CAP_PROP_WB_TEMPERATURE,
    "autofocus": cv2.CAP_PROP_AUTOFOCUS, "focus": cv2.CAP_PROP_FOCUS,
}


def fourcc_code(text: str) -> float:
    if len(text) != 4:
        raise ValueError(f"fourcc must be 4 characters like 'MJPG', got {text!r}")
    return float(sum(ord(c) << (8 * i) for i, c in enumerate(text)))


def apply_controls(cap: Any, controls: dict[str, float]) -> tuple[dict[str, float], list[str]]:
    """Set each control (in ``CONTROLS`` order: size and format before exposure), read it
    back; returns what the device reports and the names of the controls it refused (``set``
    failed, or the value read back differs)."""
    refused: list[str] = []
    got: dict[str, float] = {}
    for name in CONTROLS:
        if name not in controls:
            continue
        want = controls[name]
        ok = bool(cap.set(CONTROLS[name], want))
        got[name] = float(cap.get(CONTROLS[name]))
        tolerance = 0.5 if name in ("width", "height", "fps") else 1e-3 * max(1.0, abs(want))
        if not ok or not math.isclose(got[name], want, abs_tol=tolerance):
            refused.append(name)
    return got, refused


class Capture:
    """A cv2.VideoCapture: camera index ("0"), video file, or RTSP/HTTP URL."""

    def __init__(self, spec: str, loop: bool = True,
                 controls: dict[str, float] | None = None) -> None:
        target: int | str = int(spec) if spec.isdigit() else spec
        self.cap = cv2.VideoCapture(target)
        self.spec, self.loop = spec, loop
        self.is_file = not spec.isdigit() and Path(spec).is_file()
        if not self.cap.isOpened():
            self.cap.release()
            raise SourceLostError(f"cannot open video source {spec!r}")
        self.stamp_source: StampSource = "container" if self.is_file else "grab"
        self.controls: dict[str, float] = {}
        self.refused: list[str] = []
        if not self.is_file:
            self.cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # the newest frame, not a queued one
            if controls:
                self.controls, self.refused = apply_controls(self.cap, controls)
        self._playback_start_ns = time.time_ns()
        self.description = f"video source {spec}"

    def read(self) -> Grabbed:
        grabbed_at = time.time_ns()
        if self.cap.grab():
            ok, image = self.cap.retrieve()
            if ok and image is not None:
                return Grabbed(image, self._stamp(grabbed_at), self.stamp_source)
        if self.is_file:
            if self.loop:
                self.cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
                self._playback_start_ns = time.time_ns()
                return self.read()
            raise SourceEndedError(f"video file {self.spec} ended")
        raise SourceLostError(f"video source {self.spec!r} returned no frame (unplugged?)")

    def _stamp(self, grabbed_at: int) -> int:
        if not self.is_file:
            return grabbed_at
        return self._playback_start_ns + int(self.cap.get(cv2.CAP_PROP_POS_MSEC) * 1e6)

    def close(self) -> None:
        self.cap.release()


def open_source(spec: str, loop: bool = True, controls: dict[str, float] | None = None
                ) -> ImageFiles | Capture:
    """Open a source by its spec; raises SourceLostError with the reason when it cannot.
    ``controls`` (``CONTROLS`` names) apply to live cameras only."""
    path = Path(spec)
    if path.is_dir() or any(c in spec for c in "*?[") or path.suffix.lower() in IMAGE_SUFFIXES:
        return ImageFiles(spec, loop)
    return Capture(spec, loop, controls)
