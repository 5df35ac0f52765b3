"""The ``vertex_extractor`` service: ``camera/frame`` (latest only) -> ``marker/vertices``."""

from __future__ import annotations

import asyncio

import cv2
from pydantic import BaseModel, ConfigDict, Field

from schemas import FrameEncoding, MarkerVertices
from schemas.keys import VERTICES
from services.config import ServiceSettings
from services.vertex_extractor.colour import ColourModel
from services.vertex_extractor.extractor import (
    Detection,
    ExtractorParams,
    RhombusExtractor,
    warm_up,
)


class ColourSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")
    min_score: float = Field(default=60.0, gt=0)
    green_ratio: float = Field(default=0.35, gt=0, le=1)
    balance: float = Field(default=0.2, gt=0, le=1)
    min_level: int = Field(default=50, ge=0, le=255)


class Settings(ServiceSettings):
    dx: int = Field(default=1, ge=1, le=8, description="column step Δx (px)")
    min_len_px: int = Field(default=12, ge=4, description="MIN_LEN (px)")
    window: int = Field(default=5, ge=2, le=12, description="sub-pixel window (rows)")
    min_area_px: float = Field(default=200.0, gt=0)
    max_residual_px: float = Field(default=0.8, gt=0)
    colour: ColourSettings = Field(default_factory=ColourSettings)


def params_from(config: Settings) -> ExtractorParams:
    return ExtractorParams(colour=ColourModel(**config.colour.model_dump()), dx=config.dx,
                           min_len_px=config.min_len_px, window=config.window,
                           min_area_px=config.min_area_px,
                           max_residual_px=config.max_residual_px)


def to_message(det: Detection, seq: int, stamp_ns: int, width: int, height: int
               ) -> MarkerVertices:
    verts = (tuple((float(u), float(v)) for u, v in det.vertices_px)
             if det.found and det.vertices_px is not None else None)
    return MarkerVertices(seq=seq, stamp_ns=stamp_ns, found=det.found,
                          vertices_px=verts, area_ratio=det.area_ratio,  # type: ignore[arg-type]
                          residual_px=det.residual_px, reason=det.reason, width=width,
                          height=height)


async def main(ctx, config: Settings) -> None:
    bus, log = ctx.bus, ctx.log
    params = params_from(config)
    await asyncio.to_thread(warm_up, params)  # compiled kernels ready before the first frame
    extractor = RhombusExtractor(params)
    frames = bus.subscribe_frames(latest=True)
    async for frame in frames:
        h = frame.header
        image = frame.image
        if h.encoding is FrameEncoding.MONO8:
            det = Detection(False, reason="mono8 frame: the colour marker needs a colour image")
        else:
            try:
                det = extractor.extract(image if image.ndim == 3 else
                                        cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
            except Exception as err:
                log.exception("extractor failed on frame %d", h.seq)
                extractor.reset()
                det = Detection(False, reason=f"internal error: {err}")
        bus.put(VERTICES, to_message(det, h.seq, h.stamp_ns, h.width, h.height))
