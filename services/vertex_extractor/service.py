"""The ``vertex_extractor`` service: ``camera/frame`` (latest only) -> ``marker/vertices``."""

from __future__ import annotations

import asyncio

import cv2
from pydantic import Field, model_validator

from schemas import FrameEncoding, MarkerVertices
from schemas.keys import VERTICES
from services.runtime.config import RelPath, ServiceSettings
from services.runtime.context import ServiceContext
from services.vertex_extractor.extractor import (
    Detection,
    ExtractorParams,
    RhombusExtractor,
    warm_up,
)
from services.vertex_extractor.learn import load_colour_file


class Settings(ServiceSettings, ExtractorParams):
    """The extractor's parameters (``ExtractorParams``), and ``colour_file``: a colour model
    written by ``shepherd marker learn`` (relative to the deployment file), which replaces
    ``colour``."""

    colour_file: RelPath | None = Field(default=None, description=(
        "a colour model from shepherd marker learn; replaces colour"))

    @model_validator(mode="after")
    def _load_colour(self) -> Settings:
        if self.colour_file is not None:
            object.__setattr__(self, "colour", load_colour_file(self.colour_file))
        return self


def to_message(det: Detection, seq: int, stamp_ns: int, width: int, height: int
               ) -> MarkerVertices:
    verts = (tuple((float(u), float(v)) for u, v in det.vertices_px)
             if det.found and det.vertices_px is not None else None)
    cov = (tuple(tuple(tuple(float(x) for x in row) for row in c) for c in det.vertices_cov_px2)
           if verts is not None and det.vertices_cov_px2 is not None else None)
    return MarkerVertices(seq=seq, stamp_ns=stamp_ns, found=det.found,
                          vertices_px=verts, area_ratio=det.area_ratio,  # type: ignore[arg-type]
                          residual_px=det.residual_px, reason=det.reason, width=width,
                          height=height, vertices_cov_px2=cov)  # type: ignore[arg-type]


async def main(ctx: ServiceContext, config: Settings) -> None:
    bus, log = ctx.bus, ctx.log
    params = config.part(ExtractorParams)
    frames = bus.subscribe_frames(latest=True)
    await asyncio.to_thread(warm_up, params)  # compiled kernels ready before the first frame
    g = ctx.geometry
    extractor = RhombusExtractor(params, g.marker_width_m / g.marker_height_m)
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
