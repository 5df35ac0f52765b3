"""The ``camera_planner`` service: humanoid pose + camera odometry -> ``camera/goal`` and
``mission/hold`` (paper section 6). The goal is smoothed (exponential, with a dead band) so it
does not jitter with pose noise."""

from __future__ import annotations

import math
from dataclasses import dataclass

from pydantic import Field

from schemas import CameraGoal, CameraPose, Hold, HumanoidPose
from schemas.keys import CAMERA_GOAL, HUMANOID_POSE, MISSION_HOLD, ODOM
from services.camera_planner.planner import CameraPlanner, PlannerParams
from services.core.geometry import wrap_angle
from services.runtime.clock import Ticker, age_s
from services.runtime.config import ServiceSettings
from services.runtime.context import ServiceContext

Pose = tuple[float, float, float]


class Settings(ServiceSettings, PlannerParams):
    """The planner's parameters (``PlannerParams``) and the service loop's own."""

    rate_hz: float = Field(default=5.0, gt=0.0, description="plans per second")
    smoothing: float = Field(default=0.5, gt=0.0, le=1.0, description="weight of a new goal")
    deadband_m: float = Field(default=0.005, ge=0.0,
                              description="a goal that moved less is not sent again")
    pose_timeout_s: float = Field(default=1.0, gt=0.0,
                                  description="plan only from a pose that arrived this recently")


@dataclass
class GoalFilter:
    """Smooths the planner's goals and decides when one is worth publishing."""

    smoothing: float
    deadband_m: float
    goal: Pose | None = None
    published: Pose | None = None
    holding: bool = False

    def update(self, new: Pose, hold: bool) -> Pose | None:
        """The smoothed goal, if it moved enough to publish (a hold change resets it)."""
        a, g = self.smoothing, self.goal
        self.goal = new if g is None or hold != self.holding else (
            g[0] + a * (new[0] - g[0]), g[1] + a * (new[1] - g[1]),
            g[2] + a * wrap_angle(new[2] - g[2]))
        self.holding = hold
        p, g = self.published, self.goal
        if p is None or math.hypot(g[0] - p[0], g[1] - p[1]) > self.deadband_m or \
                abs(wrap_angle(g[2] - p[2])) > math.radians(2):
            self.published = g
            return g
        return None


async def main(ctx: ServiceContext, config: Settings) -> None:
    bus, log = ctx.bus, ctx.log
    planner = CameraPlanner(config.part(PlannerParams), ctx.world, ctx.geometry)
    poses = bus.subscribe(HUMANOID_POSE, HumanoidPose, latest=True)
    odom = bus.subscribe(ODOM, CameraPose, latest=True)
    goals = GoalFilter(config.smoothing, config.deadband_m)
    humanoid: Pose | None = None
    camera: Pose | None = None
    ticker = Ticker(1.0 / config.rate_hz)
    try:
        while True:
            if (p := poses.get_nowait()) is not None and p.x is not None and p.y is not None \
                    and p.yaw is not None:
                humanoid = (p.x, p.y, p.yaw)
            if (o := odom.get_nowait()) is not None:
                camera = (o.x, o.y, o.yaw)
            fresh = age_s(poses.last_received_ns) < config.pose_timeout_s
            if fresh and humanoid is not None and camera is not None:
                try:
                    was_holding = goals.holding
                    plan = planner.plan(humanoid, camera)
                    if (goal := goals.update(plan.goal, plan.hold)) is not None:
                        bus.put(CAMERA_GOAL, CameraGoal(x=goal[0], y=goal[1], yaw=goal[2],
                                                        reason=plan.reason))
                    if plan.hold or was_holding:
                        bus.put(MISSION_HOLD, Hold(hold=plan.hold, reason=(
                            f"view {math.degrees(plan.view_angle_rad):.0f} deg off the marker "
                            f"normal; {plan.reason}")))
                except Exception:
                    log.exception("planning failed for humanoid %s, camera %s", humanoid, camera)
                    goals = GoalFilter(config.smoothing, config.deadband_m)
            await ticker.wait()
    finally:
        if goals.holding:
            bus.put(MISSION_HOLD, Hold(hold=False, reason="camera planner stopped"))
