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

from schemas import Command, Phase
from services.geometry import wrap_angle


@dataclass(frozen=True)
class ControlParams:
    turn_threshold_rad: float = math.radians(15.0)   # k
    turn_release_rad: float = math.radians(5.0)      # hysteresis: stop turning below this
    goal_tolerance_m: float = 0.02                   # l
    stop_lead_m: float = 0.01                        # stop this much early (reaction delay)
    pose_timeout_s: float = 0.3


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
    _phase: Phase = Phase.IDLE

    def set_waypoints(self, waypoints: list[tuple[float, float]]) -> None:
        self.waypoints, self.index = list(waypoints), 0
        self._phase = Phase.IDLE if not waypoints else Phase.WAITING_POSE

    def decide(self, pose: tuple[float, float, float] | None, pose_age_s: float,
               hold: bool) -> Decision:
        """One control step. ``pose`` is (x m, y m, yaw rad) in the world, or None."""
        p = self.params
        if self.index >= len(self.waypoints):
            self._phase = Phase.DONE if self.waypoints else Phase.IDLE
            return Decision(Command.STOP, self._phase, self.index)
        if pose is None or pose_age_s > p.pose_timeout_s:
            self._phase = Phase.WAITING_POSE
            return Decision(Command.STOP, Phase.WAITING_POSE, self.index)
        x, y, yaw = pose
        gx, gy = self.waypoints[self.index]
        e = math.hypot(gx - x, gy - y)
        alpha = wrap_angle(math.atan2(gy - y, gx - x) - yaw)
        if hold:
            self._phase = Phase.HOLD
            return Decision(Command.STOP, Phase.HOLD, self.index, e, alpha)
        if e <= p.goal_tolerance_m + (p.stop_lead_m if self._phase is Phase.WALKING else 0.0):
            self.index += 1
            self._phase = Phase.DONE if self.index >= len(self.waypoints) else Phase.IDLE
            if self._phase is Phase.DONE:
                return Decision(Command.STOP, Phase.DONE, self.index, e, alpha)
            return self.decide(pose, pose_age_s, hold)
        turning = self._phase is Phase.TURNING
        limit = p.turn_release_rad if turning else p.turn_threshold_rad
        if abs(alpha) > limit:
            self._phase = Phase.TURNING
            cmd = Command.TURN_LEFT if alpha > 0 else Command.TURN_RIGHT
            return Decision(cmd, Phase.TURNING, self.index, e, alpha)
        self._phase = Phase.WALKING
        return Decision(Command.WALK_FORWARD, Phase.WALKING, self.index, e, alpha)
