"""The ``frame_source`` service: publishes ``camera/frame`` from a camera, file, URL or folder.

Latest frame only, paced to ``fps``. A source that fails is logged and reopened every
``retry_s``; a file or folder that ends (``loop = false``) ends the service cleanly.
"""

from __future__ import annotations

import asyncio
import time

import cv2
from pydantic import Field

from services.frame_source.sources import SourceEndedError, SourceLostError, open_source
from services.runtime.clock import Ticker
from services.runtime.config import ServiceSettings
from services.runtime.context import ServiceContext
from services.runtime.frames import encode_frame


class Settings(ServiceSettings):
    source: str = Field(description="camera index, video file, URL, image folder or glob")
    fps: float = Field(default=30.0, gt=0.0)
    loop: bool = True
    jpeg_quality: int | None = Field(default=None, ge=10, le=100)
    width: int | None = Field(default=None, gt=0, description="resize to this width")
    height: int | None = Field(default=None, gt=0)
    retry_s: float = Field(default=1.0, gt=0.0)


async def main(ctx: ServiceContext, config: Settings) -> None:
    bus, log = ctx.bus, ctx.log
    seq = 0
    period = 1.0 / config.fps
    while True:
        try:
            source = await asyncio.to_thread(open_source, config.source, config.loop)
        except SourceLostError as err:
            log.warning("%s; retrying in %.1f s", err, config.retry_s)
            await asyncio.sleep(config.retry_s)
            continue
        log.info("publishing %s at %.1f fps", source.description, config.fps)
        try:
            ticker = Ticker(period)
            while True:
                image = await asyncio.to_thread(source.read)
                stamp = time.time_ns()
                if config.width and config.height:
                    image = cv2.resize(image, (config.width, config.height),
                                       interpolation=cv2.INTER_AREA)
                header, payload = encode_frame(image, seq, stamp, config.jpeg_quality)
                bus.put_frame(header, payload)
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
