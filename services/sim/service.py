"""The ``sim`` service: steps the simulated world and publishes what a real robot would.

Subscribes ``sim/ir`` (commands the humanoid receives) and ``camera/goal``; publishes
``camera/frame`` at ``fps``, ``camera/odom``, ``sim/truth``, and answers ``camera/intrinsics``
with the simulated camera's intrinsics.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Literal

from pydantic import Field

from schemas import CameraGoal, CameraPose, IrCommand, MarkerInCamera, Pose2D, SimTruth
from schemas.keys import CAMERA_GOAL, INTRINSICS, ODOM, SIM_IR, SIM_TRUTH
from services.core.camera import CameraModel
from services.core.geometry import quaternion_from_R
from services.core.mounts import Geometry
from services.core.world import World
from services.runtime.clock import Ticker
from services.runtime.config import RelPath, ServiceSettings
from services.runtime.context import ServiceContext
from services.runtime.frames import encode_frame
from services.sim.camera_robot import CameraRobotParams
from services.sim.hazards import Hazards
from services.sim.humanoid import HumanoidParams
from services.sim.render import INKS_BGR, RenderStyle
from services.sim.state import SimWorld
from services.sim.webcam import WebcamParams


class Settings(ServiceSettings):
    fps: float = Field(default=30.0, gt=0.0, le=1000.0, description="frames per second")
    seed: int = Field(default=0, description="seed of the scene, the gait and the noise")
    intrinsics: RelPath | None = Field(default=None, description="TOML; default paper camera")
    humanoid_start: tuple[float, float, float] = Field(
        default=(0.29, 0.0, 0.0), description="x m, y m, yaw rad in the world")
    camera_start: tuple[float, float, float] = Field(
        default=(0.0, 0.0, 0.0), description="the camera robot: x m, y m, yaw rad")
    humanoid: HumanoidParams = Field(default_factory=HumanoidParams,
                                     description="the simulated Robosapien's gait")
    camera_robot: CameraRobotParams = Field(
        default_factory=CameraRobotParams, description="the camera robot and its odometry")
    noise_sigma: float = Field(default=2.0, ge=0.0,
                               description="ideal renders: Gaussian noise, grey levels")
    brightness: float = Field(default=1.0, gt=0.0, description="scene light, a gain")
    brightness_wave: float = Field(default=0.1, ge=0.0, le=0.5,
                                   description="slow lighting change, fraction")
    motion_blur_px: float = Field(default=0.0, ge=0.0, description="motion blur length")
    clutter: bool = Field(default=True,
                          description="textured background and coloured distractors")
    jpeg_quality: int | None = Field(default=None, ge=10, le=100,
                                     description="transport encoding of camera/frame")
    camera: WebcamParams = Field(default_factory=WebcamParams,
                                 description="the simulated webcam; ideal = true: ideal renders")
    photos: bool = Field(default=True, description="photographed walls and floor (webcam)")
    hazards: Hazards = Field(default_factory=Hazards,
                             description="shadows, occluders, highlights, distractors (webcam)")
    ink: Literal["nominal", "process", "bluish"] = Field(
        default="nominal", description="the marker's printed ink (render.INKS_BGR)")
    realtime: bool = Field(default=True, description="pace frames to the wall clock")
    speedup: float = Field(default=1.0, gt=0.0, description="simulated s per wall-clock s")


def build_world(config: Settings, geometry: Geometry, world: World) -> SimWorld:
    camera = CameraModel.load(config.intrinsics) if config.intrinsics else CameraModel.paper()
    style = RenderStyle(seed=config.seed, brightness=config.brightness,
                        noise_sigma=config.noise_sigma, motion_blur_px=config.motion_blur_px,
                        clutter=config.clutter, distractors=config.clutter,
                        marker_bgr=INKS_BGR[config.ink], camera=config.camera,
                        photos=config.photos,
                        hazards=config.hazards if config.hazards.any else None)
    return SimWorld(camera=camera, geometry=geometry, world=world,
                    humanoid_start=config.humanoid_start, camera_start=config.camera_start,
                    humanoid=config.humanoid, camera_robot=config.camera_robot, style=style,
                    seed=config.seed)


class OdometryFeed:
    """Samples the camera robot's odometry at its own rate (sim time) and releases each
    sample ``latency_s`` after its stamp, as a real locating system would."""

    def __init__(self, hz: float, latency_s: float) -> None:
        self.period_s, self.latency_ns = 1.0 / hz, int(latency_s * 1e9)
        self._next_s = 0.0
        self._queue: deque[CameraPose] = deque(maxlen=256)

    def tick(self, sim_time_s: float, now_ns: int,
             read: Callable[[], tuple[float, float, float]]) -> list[CameraPose]:
        if sim_time_s >= self._next_s:
            self._next_s += self.period_s * max(1, math.ceil(
                (sim_time_s - self._next_s) / self.period_s))
            x, y, yaw = read()
            self._queue.append(CameraPose(stamp_ns=now_ns, x=x, y=y, yaw=yaw))
        out = []
        while self._queue and self._queue[0].stamp_ns + self.latency_ns <= now_ns:
            out.append(self._queue.popleft())
        return out


async def main(ctx: ServiceContext, config: Settings) -> None:
    bus = ctx.bus
    sim = build_world(config, ctx.geometry, ctx.world)
    bus.declare_queryable(INTRINSICS, sim.camera.to_message)
    bus.put(INTRINSICS, sim.camera.to_message())
    commands = bus.subscribe(SIM_IR, IrCommand, latest=False, queue=32)
    goals = bus.subscribe(CAMERA_GOAL, CameraGoal)
    dt = 1.0 / config.fps
    base_style = sim.style
    ticker = Ticker(dt / config.speedup)
    seq = 0
    odometry = OdometryFeed(sim.robot.params.odom_hz, sim.robot.params.odom_latency_s)
    loop = asyncio.get_running_loop()
    renderer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sim-render")
    try:
        while True:
            while (cmd := commands.get_nowait()) is not None:
                sim.command(cmd.command)
            if (goal := goals.get_nowait()) is not None:
                sim.robot.goal = (goal.x, goal.y, goal.yaw)
            sim.step(dt)
            if config.brightness_wave:
                gain = 1.0 + config.brightness_wave * math.sin(2 * math.pi * sim.time_s / 7.0)
                sim.style = RenderStyle(**{**base_style.__dict__,
                                           "brightness": base_style.brightness * gain})
            # off the event loop (numpy and OpenCV release the GIL), always on the same thread so
            # that its allocations stay in one malloc arena
            rendered = await loop.run_in_executor(renderer, sim.render)
            stamp = time.time_ns()
            # odometry on its own rate, published its latency after its stamp
            for sample in odometry.tick(sim.time_s, stamp, sim.robot.odometry):
                bus.put(ODOM, sample)
            T = rendered.T_camera_marker
            h, r = sim.humanoid, sim.robot
            bus.put(SIM_TRUTH, SimTruth(
                stamp_ns=stamp, seq=seq, humanoid=Pose2D(x=h.x, y=h.y, yaw=h.yaw),
                camera=Pose2D(x=r.x, y=r.y, yaw=r.yaw),
                marker_in_camera=MarkerInCamera(position=tuple(T[:3, 3]),  # type: ignore[arg-type]
                                                quaternion=quaternion_from_R(T[:3, :3]))))
            header, payload = encode_frame(rendered.image, seq, stamp, config.jpeg_quality)
            bus.put_frame(header, payload)
            seq += 1
            if config.realtime:
                await ticker.wait()
            else:
                await asyncio.sleep(0)
    finally:
        renderer.shutdown(wait=False, cancel_futures=True)
