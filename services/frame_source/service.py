"""The ``frame_source`` service: publishes ``camera/frame`` from a camera, file, URL or folder.

Latest frame only, paced to ``fps``, each stamped with the time it was taken (``sources``
says which clock). Camera controls in the table are applied to a live camera and read back;
each control the device refused is named in a warning. Frames come out ``width`` x
``height`` when those are set; with ``intrinsics`` (a calibration of the camera at any size)
the service serves ``camera/intrinsics`` scaled to the frames it publishes. A source that fails
is logged and reopened every ``retry_s``; a file or folder that ends (``loop = false``) ends
the service cleanly.
"""

from __future__ import annotations

import asyncio

import cv2
from pydantic import Field, model_validator

from schemas import CameraIntrinsics
from schemas.keys import INTRINSICS
from services.core.camera import CameraModel
from services.frame_source.sources import (
    SourceEndedError,
    SourceLostError,
    fourcc_code,
    open_source,
)
from services.runtime.clock import Ticker
from services.runtime.config import RelPath, ServiceSettings
from services.runtime.context import ServiceContext
from services.runtime.frames import encode_frame

STAMP_CLOCKS = {"grab": "the grab time", "container": "the video file's own timestamps",
                "read": "the time each image was read"}


class Settings(ServiceSettings):
    source: str = Field(description="camera index, video file, URL, image folder or glob")
    fps: float = Field(default=30.0, gt=0.0, description="pace, and asked of a live camera")
    loop: bool = Field(default=True, description="a video file or folder starts again")
    jpeg_quality: int | None = Field(default=None, ge=10, le=100,
                                     description="transport encoding of camera/frame")
    width: int | None = Field(default=None, gt=0, description="frames out (px); with height")
    height: int | None = Field(default=None, gt=0, description="frames out (px); with width")
    fourcc: str | None = Field(default=None, min_length=4, max_length=4,
                               description="a live camera's pixel format, e.g. MJPG")
    auto_exposure: float | None = Field(default=None, description="V4L2: 1 manual, 3 auto")
    exposure: float | None = Field(default=None, description="manual exposure (device units)")
    auto_white_balance: bool | None = Field(default=None, description="a live camera's")
    white_balance: float | None = Field(default=None, description="colour temperature (K)")
    autofocus: bool | None = Field(default=None, description="best off: focus fixed")
    focus: float | None = Field(default=None, description="manual focus (device units)")
    intrinsics: RelPath | None = Field(default=None, description=(
        "calibration TOML; served on camera/intrinsics scaled to the frames published"))
    retry_s: float = Field(default=1.0, gt=0.0, description="reopen a lost source after")

    @model_validator(mode="after")
    def _both_sides(self) -> Settings:
        if (self.width is None) != (self.height is None):
            raise ValueError("width and height go together: set both or neither")
        return self

    def controls(self) -> dict[str, float]:
        """The camera controls this table asks for (``sources.CONTROLS`` names)."""
        asked: dict[str, float | bool | None] = {
            "width": self.width, "height": self.height, "fps": self.fps,
            "auto_exposure": self.auto_exposure, "exposure": self.exposure,
            "auto_white_balance": self.auto_white_balance,
            "white_balance": self.white_balance, "autofocus": self.autofocus,
            "focus": self.focus}
        out = {k: float(v) for k, v in asked.items() if v is not None}
        if self.fourcc is not None:
            out["fourcc"] = fourcc_code(self.fourcc)
        return out


async def main(ctx: ServiceContext, config: Settings) -> None:
    bus, log = ctx.bus, ctx.log
    seq = 0
    period = 1.0 / config.fps
    calibrated = CameraModel.load(config.intrinsics) if config.intrinsics else None
    served: list[CameraIntrinsics] = []  # the intrinsics of the frames published, once known
    bus.declare_queryable(INTRINSICS, lambda: served[-1] if served else None)
    while True:
        try:
            source = await asyncio.to_thread(open_source, config.source, config.loop,
                                             config.controls())
        except SourceLostError as err:
            log.warning("%s; retrying in %.1f s", err, config.retry_s)
            await asyncio.sleep(config.retry_s)
            continue
        log.info("publishing %s at %.1f fps, stamped with %s", source.description, config.fps,
                 STAMP_CLOCKS[source.stamp_source])
        for name in source.refused:
            log.warning("the camera refused %s = %s (it reports %s)", name,
                        config.controls()[name], source.controls.get(name))
        try:
            ticker = Ticker(period)
            warned_size = False
            while True:
                frame = await asyncio.to_thread(source.read)
                image = frame.image
                h, w = image.shape[:2]
                if config.width and config.height and (w, h) != (config.width, config.height):
                    if not warned_size:
                        log.warning("frames are %dx%d: resized to %dx%d", w, h, config.width,
                                    config.height)
                        warned_size = True
                    image = cv2.resize(image, (config.width, config.height),
                                       interpolation=cv2.INTER_AREA)
                out_h, out_w = image.shape[:2]
                if calibrated is not None and (not served or (
                        served[-1].width, served[-1].height) != (out_w, out_h)):
                    served.append(calibrated.resized(out_w, out_h).to_message())
                    del served[:-1]
                    log.info("intrinsics %s scaled from %dx%d to %dx%d", config.intrinsics,
                             calibrated.width, calibrated.height, out_w, out_h)
                if served and seq % max(1, round(config.fps)) == 0:  # about once a second
                    bus.put(INTRINSICS, served[-1])
                header, payload = encode_frame(image, seq, frame.stamp_ns, config.jpeg_quality)
                bus.put_frame(header.model_copy(update={"stamp_source": frame.stamp_source}),
                              payload)
                seq += 1
                await ticker.wait()
        except SourceEndedError as err:
            log.info("%s; frame source done after %d frames", err, seq)
            return
        except SourceLostError as err:
            log.warning("%s; reopening in %.1f s", err, config.retry_s)
            await asyncio.sleep(config.retry_s)
        finally:
            source.close()
