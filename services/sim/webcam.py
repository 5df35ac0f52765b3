"""What a webcam does to a scene: the simulator's camera model (the ``[services.sim.camera]``
table).

The scene comes in as linear light (BGR float32, 1.0 = a white surface at nominal exposure) and
leaves as the 8-bit sRGB (or gamma) BGR image a webcam delivers. Stages, each switchable, in the
order light meets them: vignetting, lateral chromatic aberration, optics blur (Gaussian), exposure,
an RGGB Bayer mosaic, shot and read noise (in electrons), white-balance gains, clipping, OpenCV
demosaicing (16-bit), the transfer curve, 8 bits, JPEG through OpenCV (4:2:0 chroma). A rolling
shutter is not modelled (it needs motion within a frame; the renderer draws one instant).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Literal

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

_DEMOSAIC = {  # OpenCV names the pattern by the second row's first two pixels: RGGB = "BG"
    "bilinear": cv2.COLOR_BayerBG2BGR,
    "edge_aware": cv2.COLOR_BayerBG2BGR_EA,
}


class WebcamParams(BaseModel):
    """The simulated camera. ``ideal = true`` skips every stage (the renderer's own 8-bit
    area-exact output, as before the webcam existed)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    ideal: bool = Field(default=False, description=(
        "ideal renders instead (8-bit sRGB, Gaussian noise): none of the below"))
    blur_sigma_px: float = Field(default=0.6, ge=0.0, le=5.0, description="optics PSF, px")
    exposure: float = Field(default=0.8, gt=0.0, le=16.0,
                            description="gain on scene light (0.8: white below clipping)")
    bayer: bool = Field(default=True, description="an RGGB mosaic, demosaiced by OpenCV")
    demosaic: Literal["bilinear", "edge_aware"] = Field(
        default="bilinear", description="OpenCV's demosaicing method")
    full_well_e: float = Field(default=4000.0, gt=0.0,
                               description="electrons at full scale (shot noise); 0 noise off")
    shot_noise: bool = Field(default=True, description="photon (Poisson) noise")
    read_noise_e: float = Field(default=6.0, ge=0.0, description="read noise, electrons RMS")
    white_balance: tuple[float, float, float] = Field(
        default=(1.0, 1.0, 1.0), description="gains on R, G, B after the sensor (1 = balanced)")
    transfer: Literal["srgb", "gamma", "linear"] = Field(
        default="srgb", description="the curve from linear light to 8-bit values")
    gamma: float = Field(default=2.2, gt=0.5, le=4.0, description="used when transfer = gamma")
    jpeg_quality: int = Field(default=90, ge=0, le=100, description="0: no JPEG")
    vignetting: float = Field(default=0.0, ge=0.0, le=0.9,
                              description="light lost at the image corner, fraction")
    chromatic_aberration_px: float = Field(
        default=0.0, ge=0.0, le=5.0,
        description="lateral CA: red outward and blue inward by this much at the corner, px")


def srgb_to_linear(srgb: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 inverse transfer, values 0..1."""
    srgb = np.asarray(srgb, np.float32)
    return np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 transfer, values 0..1."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


@lru_cache(maxsize=4)
def _encode_table(transfer: str, gamma: float) -> np.ndarray:
    """16-bit linear value -> 8-bit encoded value (the transfer curve, rounded)."""
    x = np.arange(65536) / 65535.0
    if transfer == "srgb":
        out = linear_to_srgb(x)
    elif transfer == "gamma":
        out = np.power(x, 1.0 / gamma)
    else:
        out = x
    return np.clip(out * 255.0 + 0.5, 0, 255).astype(np.uint8)


def _radial_scale(channel: np.ndarray, shift_px: float) -> np.ndarray:
    """One channel magnified about the image centre so its corner moves ``shift_px``."""
    h, w = channel.shape
    cx, cy = (w - 1) / 2, (h - 1) / 2
    s = 1.0 + shift_px / np.hypot(cx, cy)
    M = np.array([[s, 0, cx * (1 - s)], [0, s, cy * (1 - s)]], np.float32)
    return cv2.warpAffine(channel, M, (w, h), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)


def _mosaic(bgr: np.ndarray) -> np.ndarray:
    """RGGB raw (H x W) from a full-colour BGR image: R at (even, even), B at (odd, odd)."""
    raw = bgr[..., 1].copy()
    raw[0::2, 0::2] = bgr[0::2, 0::2, 2]
    raw[1::2, 1::2] = bgr[1::2, 1::2, 0]
    return raw


def _mosaic_gains(shape: tuple[int, int], bgr_gains: tuple[float, float, float]) -> np.ndarray:
    gains = np.full(shape, bgr_gains[1], np.float32)
    gains[0::2, 0::2] = bgr_gains[2]
    gains[1::2, 1::2] = bgr_gains[0]
    return gains


def expose(scene_linear_bgr: np.ndarray, params: WebcamParams,
           rng: np.random.Generator) -> np.ndarray:
    """The webcam's 8-bit BGR image of a linear-light BGR scene (H x W x 3 float32)."""
    img = np.asarray(scene_linear_bgr, np.float32)
    h, w = img.shape[:2]
    if params.vignetting > 0:
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
        img = img * (1.0 - params.vignetting * r2)[..., None]
    if params.chromatic_aberration_px > 0:
        img = img.copy()
        img[..., 2] = _radial_scale(img[..., 2], params.chromatic_aberration_px)
        img[..., 0] = _radial_scale(img[..., 0], -params.chromatic_aberration_px)
    if params.blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), params.blur_sigma_px)
    img = img * params.exposure
    wb = (params.white_balance[2], params.white_balance[1], params.white_balance[0])  # B, G, R
    raw = _mosaic(img) if params.bayer else img
    full = params.full_well_e
    electrons = np.clip(raw, 0.0, None) * full
    # shot noise (Poisson, by its normal approximation: exact enough above ~10 e) and read noise
    sigma = np.sqrt(electrons + params.read_noise_e ** 2) if params.shot_noise else (
        np.float32(params.read_noise_e))
    if params.shot_noise or params.read_noise_e > 0:
        electrons = electrons + sigma * rng.standard_normal(electrons.shape, np.float32)
    signal = electrons / full
    signal = signal * (_mosaic_gains(signal.shape[:2], wb) if params.bayer
                       else np.array(wb, np.float32))
    raw16 = (np.clip(signal, 0.0, 1.0) * 65535.0 + 0.5).astype(np.uint16)
    if params.bayer:
        raw16 = cv2.cvtColor(raw16, _DEMOSAIC[params.demosaic])
    image = _encode_table(params.transfer, params.gamma)[raw16]
    if params.jpeg_quality > 0:
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, params.jpeg_quality])
        if ok:
            image = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return image
