"""The ``camera_planner`` service: humanoid pose + camera odometry -> ``camera/goal`` and
``mission/hold`` (paper section 6). The goal is smoothed (exponential, with a dead band) so it
does not jitter with pose noise."""

from __future__ import annotations

import asyncio
import math
import time

from pydantic import Field

from schemas import CameraGoal, CameraPose, Hold, HumanoidPose
from schemas.keys import CAMERA_GOAL, HUMANOID_POSE, MISSION_HOLD, ODOM
from services.camera_planner.planner import CameraPlanner, PlannerParams
from services.config import ServiceSettings
from services.geometry import wrap_angle


class Settings(ServiceSettings):
    distance_m: float = Field(default=0.25, gt=0.0, description="d")
    critical_angle_deg: float = Field(default=50.0, gt=0.0, lt=90.0, description="theta")
    release_deg: float = Field(default=15.0, ge=0.0, lt=90.0)
    rate_hz: float = Field(default=5.0, gt=0.0)
    smoothing: float = Field(default=0.5, gt=0.0, le=1.0, description="weight of a new goal")
    deadband_m: float = Field(default=0.005, ge=0.0)
    pose_timeout_s: float = Field(default=1.0, gt=0.0)


async def main(ctx, config: Settings) -> None:
    bus, dep = ctx.bus, ctx.deployment
    g = dep.geometry
    planner = CameraPlanner(PlannerParams(
        distance_m=config.distance_m, critical_angle_rad=math.radians(config.critical_angle_deg),
        release_rad=math.radians(config.release_deg), camera_forward_m=g.camera_forward_m,
        marker_back_offset_m=g.marker_back_offset_m), dep.world)
    poses = bus.subscribe(HUMANOID_POSE, HumanoidPose, latest=True)
    odom = bus.subscribe(ODOM, CameraPose, latest=True)
    humanoid = camera = None
    pose_mono = 0.0
    goal: tuple[float, float, float] | None = None
    published: tuple[float, float, float] | None = None
    was_holding = False
    try:
        while True:
            if (p := poses.get_nowait()) is not None and p.x is not None:
                humanoid, pose_mono = (p.x, p.y, p.yaw), time.monotonic()
            if (o := odom.get_nowait()) is not None:
                camera = (o.x, o.y, o.yaw)
            fresh = humanoid is not None and time.monotonic() - pose_mono < config.pose_timeout_s
            if fresh and camera is not None:
                plan = planner.plan(humanoid, camera)  # type: ignore[arg-type]
                a = config.smoothing
                goal = plan.goal if goal is None or plan.hold != was_holding else (
                    goal[0] + a * (plan.goal[0] - goal[0]), goal[1] + a * (plan.goal[1] - goal[1]),
                    goal[2] + a * wrap_angle(plan.goal[2] - goal[2]))
                if published is None or math.hypot(goal[0] - published[0],
                                                   goal[1] - published[1]) > config.deadband_m \
                        or abs(wrap_angle(goal[2] - published[2])) > math.radians(2):
                    bus.put(CAMERA_GOAL, CameraGoal(x=goal[0], y=goal[1], yaw=goal[2],
                                                    reason=plan.reason))
                    published = goal
                if plan.hold or was_holding:
                    bus.put(MISSION_HOLD, Hold(hold=plan.hold, reason=(
                        f"view {math.degrees(plan.view_angle_rad):.0f} deg off the marker "
                        f"normal; {plan.reason}")))
                was_holding = plan.hold
            await asyncio.sleep(1.0 / config.rate_hz)
    finally:
        if was_holding:
            bus.put(MISSION_HOLD, Hold(hold=False, reason="camera planner stopped"))
