"""The ``calibration`` service: serves an intrinsics file on ``camera/intrinsics`` (a
queryable, and a put at start and every ``republish_s``)."""

from __future__ import annotations

from pydantic import Field

from schemas.keys import INTRINSICS
from services.core.camera import CameraModel
from services.runtime.clock import Ticker
from services.runtime.config import RelPath, ServiceSettings
from services.runtime.context import ServiceContext


class Settings(ServiceSettings):
    intrinsics: RelPath = Field(description="TOML written by shepherd calibrate intrinsics")
    republish_s: float = Field(default=5.0, gt=0.0, description="put it again this often")


async def main(ctx: ServiceContext, config: Settings) -> None:
    camera = CameraModel.load(config.intrinsics)  # a bad file raises with its name and key
    message = camera.to_message()
    ctx.bus.declare_queryable(INTRINSICS, lambda: message)
    ctx.log.info("serving %s: %dx%d fx=%.1f", config.intrinsics, camera.width, camera.height,
                 camera.K[0, 0])
    ticker = Ticker(config.republish_s)
    while True:
        ctx.bus.put(INTRINSICS, message)
        await ticker.wait()
