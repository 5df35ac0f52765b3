"""Where frames come from: anything cv2.VideoCapture opens, or an image folder / glob."""

from __future__ import annotations

import glob
from pathlib import Path

import cv2
import numpy as np

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".gif", ".webp"}


class SourceEndedError(Exception):
    """The source has no more frames (a file or folder that ended, not looping)."""


class SourceLostError(Exception):
    """The source failed (device unplugged, stream dropped); it may come back."""


class ImageFiles:
    """Images from a folder or a glob pattern, in name order, looped or once."""

    def __init__(self, spec: str, loop: bool = True) -> None:
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

    def read(self) -> np.ndarray:
        if self._i >= len(self.files):
            if not self.loop:
                raise SourceEndedError(f"all {len(self.files)} images sent")
            self._i = 0
        path = self.files[self._i]
        self._i += 1
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise SourceLostError(f"cannot decode image {path}")
        return image

    def close(self) -> None:
        pass


class Capture:
    """A cv2.VideoCapture: camera index ("0"), video file, or RTSP/HTTP URL."""

    def __init__(self, spec: str, loop: bool = True) -> None:
        target: int | str = int(spec) if spec.isdigit() else spec
        self.cap = cv2.VideoCapture(target)
        self.spec, self.loop = spec, loop
        self.is_file = not spec.isdigit() and Path(spec).is_file()
        if not self.cap.isOpened():
            self.cap.release()
            raise SourceLostError(f"cannot open video source {spec!r}")
        self.description = f"video source {spec}"

    def read(self) -> np.ndarray:
        ok, image = self.cap.read()
        if ok and image is not None:
            return image
        if self.is_file:
            if self.loop:
                self.cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
                ok, image = self.cap.read()
                if ok:
                    return image
            raise SourceEndedError(f"video file {self.spec} ended")
        raise SourceLostError(f"video source {self.spec!r} returned no frame (unplugged?)")

    def close(self) -> None:
        self.cap.release()


def open_source(spec: str, loop: bool = True) -> ImageFiles | Capture:
    """Open a source by its spec; raises SourceLostError with the reason when it cannot."""
    path = Path(spec)
    if path.is_dir() or any(c in spec for c in "*?[") or path.suffix.lower() in IMAGE_SUFFIXES:
        return ImageFiles(spec, loop)
    return Capture(spec, loop)
