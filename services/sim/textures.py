"""Real photographs for the simulator's walls and floor, in linear light.

The photographs are the colour images scikit-image bundles in its wheel (public domain or CC0,
see ``skimage.data``); the floor textures are its grass, gravel and brick, tinted. Without
scikit-image (it is in the ``photos`` and ``dev`` extras) a procedural texture stands in, and
``have_photos()`` says so.
"""

from __future__ import annotations

import zlib
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from services.sim.webcam import srgb_to_linear

WALL_PHOTOS = ("astronaut.png", "coffee.png", "chelsea.png", "motorcycle_left.png",
               "rocket.jpg", "ihc.png", "motorcycle_right.png", "retina.jpg")
FLOOR_TEXTURES = ("gravel.png", "grass.png", "brick.png")


def _skimage_data() -> Path | None:
    try:
        import skimage
    except ImportError:
        return None
    path = Path(skimage.__file__).parent / "data"
    return path if (path / WALL_PHOTOS[0]).exists() else None


def have_photos() -> bool:
    return _skimage_data() is not None


@lru_cache(maxsize=32)
def photo_srgb(name: str) -> np.ndarray:
    """One bundled photograph, 8-bit BGR (read-only); procedural texture without scikit-image."""
    folder = _skimage_data()
    image = None if folder is None else cv2.imread(str(folder / name), cv2.IMREAD_COLOR)
    if image is None:
        image = _procedural(zlib.crc32(name.encode()))  # stable across processes
    image.setflags(write=False)
    return image


def _procedural(seed: int, size: int = 512) -> np.ndarray:
    """Smooth coloured noise at several scales (a stand-in texture), 8-bit BGR."""
    rng = np.random.default_rng(seed)
    acc = np.zeros((size, size, 3), np.float32)
    for cells in (4, 16, 64):
        small = rng.uniform(0, 1, (cells, cells, 3)).astype(np.float32)
        acc += cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC) / cells ** 0.3
    acc = (acc - acc.min()) / np.ptp(acc)
    return np.clip(40 + 170 * acc, 0, 255).astype(np.uint8)


def crop(image: np.ndarray, width: int, height: int, rng: np.random.Generator) -> np.ndarray:
    """A random crop of ``image`` at a random scale, resized to width x height."""
    h, w = image.shape[:2]
    aspect = width / height
    scale = rng.uniform(0.5, 1.0)
    cw = int(min(w, h * aspect) * scale)
    ch = max(int(cw / aspect), 8)
    x0 = int(rng.integers(0, w - cw + 1))
    y0 = int(rng.integers(0, h - ch + 1))
    return cv2.resize(image[y0:y0 + ch, x0:x0 + cw], (width, height),
                      interpolation=cv2.INTER_AREA)


@lru_cache(maxsize=8)
def photo_scene(width: int, height: int, seed: int) -> np.ndarray:
    """A room in linear light (BGR float32, read-only): a photographed wall above a textured
    floor."""
    rng = np.random.default_rng(seed)
    horizon = int(height * rng.uniform(0.35, 0.6))
    wall = crop(photo_srgb(WALL_PHOTOS[int(rng.integers(len(WALL_PHOTOS)))]), width,
                max(horizon, 1), rng)
    floor = crop(photo_srgb(FLOOR_TEXTURES[int(rng.integers(len(FLOOR_TEXTURES)))]), width,
                 max(height - horizon, 1), rng)
    tint = np.array([rng.uniform(0.5, 0.8), rng.uniform(0.6, 0.9), rng.uniform(0.7, 1.0)],
                    np.float32)
    out = np.empty((height, width, 3), np.float32)
    out[:horizon] = srgb_to_linear(wall[:horizon] / 255.0)
    out[horizon:] = srgb_to_linear(floor[:height - horizon] / 255.0) * tint
    out.setflags(write=False)
    return out


def photograph(width: int, height: int, seed: int) -> np.ndarray:
    """A marker-less view (linear BGR float32): a crop of one of the wall photographs."""
    rng = np.random.default_rng(seed)
    name = WALL_PHOTOS[seed % len(WALL_PHOTOS)]
    return srgb_to_linear(crop(photo_srgb(name), width, height, rng) / 255.0)
