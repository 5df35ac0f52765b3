"""The ``vertex_extractor`` service: ``camera/frame`` (latest only) -> ``marker/vertices``.

With the camera's intrinsics (``intrinsics``, a file, or else ``camera/intrinsics``, asked
every ``ASK_EVERY_S`` until answered, and followed, as the pose estimator takes them) each
detection's shape is tested against the deployment's rhombus seen by that camera
(``shape.py``); without them, or
on frames of another size, the weak-perspective test alone, and the extractor learns the
camera from the marker for a marker under a highlight (``learned_camera.py``; logged when
learned). Each frame is extracted on the
service's own thread, so that a slow one (a marker fitted whole under a shadow: up to 0.3 s)
holds up no other service sharing the process's event loop.
"""

from __future__ import annotations

import asyncio
import logging
from concurrent.futures import ThreadPoolExecutor

import cv2
from pydantic import Field, model_validator

from schemas import CameraIntrinsics, FrameEncoding, MarkerVertices
from schemas.keys import INTRINSICS, VERTICES
from services.core.camera import CameraModel
from services.core.mounts import Geometry
from services.runtime.config import RelPath, ServiceSettings
from services.runtime.context import ServiceContext
from services.vertex_extractor.extractor import (
    Detection,
    ExtractorParams,
    RhombusExtractor,
    shape_warning,
    warm_up,
)
from services.vertex_extractor.learn import load_colour_file
from services.vertex_extractor.learned_camera import BAND, Solved

ASK_EVERY_S = 2.0  # camera/intrinsics asked this often until answered (s)


class Settings(ServiceSettings, ExtractorParams):
    """The extractor's parameters (``ExtractorParams``), and ``colour_file``: a colour model
    written by ``shepherd marker learn`` (relative to the deployment file), which replaces
    ``colour``."""

    colour_file: RelPath | None = Field(default=None, description=(
        "a colour model from shepherd marker learn; replaces colour"))
    intrinsics: RelPath | None = Field(default=None, description=(
        "TOML file for the shape test; else taken from camera/intrinsics when served (asked "
        f"every {ASK_EVERY_S:g} s until answered, and followed)"))

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


class IntrinsicsFollower:
    """Gives the extractor the camera's intrinsics as they come (never dies on bad ones)."""

    def __init__(self, extractor: RhombusExtractor, geometry: Geometry,
                 log: logging.Logger) -> None:
        self.extractor, self.geometry, self.log = extractor, geometry, log
        self._told_size: tuple[int, int] | None = None

    def take(self, msg: CameraIntrinsics) -> None:
        """Use these intrinsics from now on (unchanged ones cost nothing)."""
        try:
            camera = CameraModel.from_message(msg)
        except ValueError as err:
            self.log.warning("intrinsics on camera/intrinsics not used: %s", err)
            return
        old = self.extractor.intrinsics
        if old is not None and old.width == camera.width and old.height == camera.height \
                and (old.K == camera.K).all() and (old.dist == camera.dist).all():
            return
        self.extractor.use_intrinsics(camera, self.geometry)
        self._told_size = None
        self.log.info("shape test with intrinsics %dx%d fx=%.1f fy=%.1f", camera.width,
                      camera.height, camera.K[0, 0], camera.K[1, 1])

    def check_size(self, width: int, height: int) -> None:
        """Warn once when the frames are not of the intrinsics' size (no shape test then)."""
        camera = self.extractor.intrinsics
        if camera is not None and (width, height) != (camera.width, camera.height) and \
                self._told_size != (width, height):
            self._told_size = (width, height)
            self.log.warning("frames are %dx%d but the intrinsics are for %dx%d: shape test "
                             "without intrinsics", width, height, camera.width, camera.height)


async def _ask_intrinsics(ctx: ServiceContext, follower: IntrinsicsFollower) -> None:
    """Ask camera/intrinsics (the frame source's, the simulator's or the calibration's
    queryable) every ``ASK_EVERY_S`` until they come, by answer or on the topic: a server
    started after this service is still heard. Quietly none while nobody serves them."""
    while follower.extractor.intrinsics is None:
        try:
            replies = await ctx.bus.get(INTRINSICS, CameraIntrinsics, timeout=ASK_EVERY_S)
        except Exception as err:  # a closing session: the topic is still followed
            ctx.log.debug("asking camera/intrinsics failed: %s", err)
            return
        if replies and follower.extractor.intrinsics is None:
            follower.take(replies[0])
            return
        await asyncio.sleep(ASK_EVERY_S)


def _tell_learned(extractor: RhombusExtractor, told: Solved | None, log: logging.Logger
                  ) -> Solved | None:
    """Log the camera learned from the marker (no intrinsics) when first learned, and when
    its focal length moves by more than the band it is used over; returns the one told."""
    learned = extractor.learned_camera
    if learned is None or (told is not None and abs(learned.f - told.f) <= BAND * told.f):
        return told
    log.info("camera learned from the marker (no intrinsics): focal length %.0f px, principal "
             "point (%.0f, %.0f) px, from %d views; a marker under a highlight is fitted under "
             "it (serve camera/intrinsics for the calibrated one)", learned.f, learned.cx,
             learned.cy, learned.views)
    return learned


async def main(ctx: ServiceContext, config: Settings) -> None:
    bus, log = ctx.bus, ctx.log
    params = config.part(ExtractorParams)
    frames = bus.subscribe_frames(latest=True)
    updates = bus.subscribe(INTRINSICS, CameraIntrinsics, latest=True)
    await asyncio.to_thread(warm_up, params)  # compiled kernels ready before the first frame
    g = ctx.geometry
    extractor = RhombusExtractor(params, geometry=g)
    if warning := shape_warning(extractor.diagonal_ratio):
        log.warning("%s", warning)
    follower = IntrinsicsFollower(extractor, g, log)
    asking = None
    if config.intrinsics is not None:
        follower.take(CameraModel.load(config.intrinsics).to_message())
    else:
        asking = asyncio.create_task(_ask_intrinsics(ctx, follower))
    # extraction on its own thread: a marker fitted whole under a shadow (shadow.py) takes
    # up to 0.3 s, which would hold up every service sharing this loop (the IR
    # transmitter's heartbeat to the firmware's 0.4 s watchdog among them)
    worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="vertex-extractor")
    loop = asyncio.get_running_loop()
    told: Solved | None = None
    try:
        async for frame in frames:
            if config.intrinsics is None and (k := updates.get_nowait()) is not None:
                follower.take(k)
            h = frame.header
            follower.check_size(h.width, h.height)
            image = frame.image
            if h.encoding is FrameEncoding.MONO8:
                det = Detection(False, reason="mono8 frame: the colour marker needs a colour "
                                              "image")
            else:
                try:
                    det = await loop.run_in_executor(
                        worker, extractor.extract,
                        image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
                except Exception as err:
                    log.exception("extractor failed on frame %d", h.seq)
                    extractor.reset()
                    det = Detection(False, reason=f"internal error: {err}")
            bus.put(VERTICES, to_message(det, h.seq, h.stamp_ns, h.width, h.height))
            told = _tell_learned(extractor, told, log)
    finally:
        worker.shutdown(wait=False, cancel_futures=True)
        if asking is not None:
            asking.cancel()
