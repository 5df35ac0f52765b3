"""The paper's heuristic humanoid control (section 5), with hysteresis and safety stops.

With e the distance from the humanoid to the next waypoint and alpha the angle between its
heading and the direction to that waypoint: turn while |alpha| > k, else walk forward while
e > l. Departures from the paper, for a real robot: hysteresis (a turn, once started, goes
on until |alpha| < k_release, so the command does not chatter), a stop lead (stop
``stop_lead_m`` early to absorb the IR reaction delay), and ``stop`` whenever the pose is
stale or the camera planner asks to hold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from pydantic import BaseModel, ConfigDict, Field

from schemas import Command, Phase
from services.core.geometry import wrap_angle


class ControlParams(BaseModel):
    """The controller's parameters; the service's settings are these plus its own loop's.
    The only place their defaults are defined."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    turn_threshold_deg: float = Field(default=15.0, gt=0.0, lt=180.0, description="k")
    turn_release_deg: float = Field(default=5.0, gt=0.0, lt=180.0,
                                    description="hysteresis: a turn goes on down to this")
    goal_tolerance_m: float = Field(default=0.01, gt=0.0, description="l")
    stop_lead_m: float = Field(default=0.012, ge=0.0,
                               description="stop this early: IR delay x walking speed")
    pose_timeout_s: float = Field(default=0.3, gt=0.0,
                                  description="stop when the pose arrived longer ago (s)")

    @property
    def turn_threshold_rad(self) -> float:
        return math.radians(self.turn_threshold_deg)

    @property
    def turn_release_rad(self) -> float:
        return math.radians(self.turn_release_deg)


@dataclass(frozen=True)
class Decision:
    command: Command
    phase: Phase
    waypoint_index: int
    distance_m: float | None = None
    heading_error_rad: float | None = None


@dataclass
class HeuristicController:
    """Decides one command per control tick from the latest pose."""

    params: ControlParams = field(default_factory=ControlParams)
    waypoints: list[tuple[float, float]] = field(default_factory=list)
    index: int = 0
    phase: Phase = Phase.IDLE

    def set_waypoints(self, waypoints: list[tuple[float, float]]) -> None:
        self.waypoints, self.index = list(waypoints), 0
        self.phase = Phase.IDLE if not waypoints else Phase.WAITING_POSE

    def decide(self, pose: tuple[float, float, float] | None, pose_age_s: float,
               hold: bool) -> Decision:
        """One control step. ``pose`` is (x m, y m, yaw rad) in the world, or None."""
        p = self.params
        if self.index >= len(self.waypoints):
            self.phase = Phase.DONE if self.waypoints else Phase.IDLE
            return Decision(Command.STOP, self.phase, self.index)
        if pose is None or pose_age_s > p.pose_timeout_s:
            self.phase = Phase.WAITING_POSE
            return Decision(Command.STOP, Phase.WAITING_POSE, self.index)
        x, y, yaw = pose
        gx, gy = self.waypoints[self.index]
        e = math.hypot(gx - x, gy - y)
        alpha = wrap_angle(math.atan2(gy - y, gx - x) - yaw)
        if hold:
            self.phase = Phase.HOLD
            return Decision(Command.STOP, Phase.HOLD, self.index, e, alpha)
        if e <= p.goal_tolerance_m + (p.stop_lead_m if self.phase is Phase.WALKING else 0.0):
            self.index += 1
            self.phase = Phase.DONE if self.index >= len(self.waypoints) else Phase.IDLE
            if self.phase is Phase.DONE:
                return Decision(Command.STOP, Phase.DONE, self.index, e, alpha)
            return self.decide(pose, pose_age_s, hold)
        turning = self.phase is Phase.TURNING
        limit = p.turn_release_rad if turning else p.turn_threshold_rad
        if abs(alpha) > limit:
            self.phase = Phase.TURNING
            cmd = Command.TURN_LEFT if alpha > 0 else Command.TURN_RIGHT
            return Decision(cmd, Phase.TURNING, self.index, e, alpha)
        self.phase = Phase.WALKING
        return Decision(Command.WALK_FORWARD, Phase.WALKING, self.index, e, alpha)
