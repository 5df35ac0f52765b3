"""The paper's heuristic humanoid control (section 5), made to work on a stepping robot.

With e the distance from the humanoid to the next waypoint and alpha the angle between its
heading and the direction to that waypoint: turn while |alpha| > k, else walk forward while
e > l. What a real Robosapien needs beyond that rule:

- hysteresis: a turn, once started, goes on until |alpha| < k_release (no chattering);
- near the goal (``near_m``) it no longer turns: the bearing of a point a step away is
  dominated by the gait's sway, so it decides only by the goal's distance along its heading;
- a stop lead: ``stop_lead_m`` early, for the IR delay and the step the robot finishes after
  ``stop``;
- settling: after a stop it waits ``settle_s`` for the last step to end before judging where
  it stopped;
- a small overshoot (or shortfall) beyond ``l`` is corrected by single steps backward (or
  forward), never by a half turn, at most ``max_corrections`` times;
- ``stop`` whenever the pose is stale or the camera planner asks to hold.

``reversals`` counts changes of walking direction and of turning direction.
"""

from __future__ import annotations

import math
import time
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
    goal_tolerance_m: float = Field(default=0.02, gt=0.0, description=(
        "l: done within this (half a stride: a stepping robot cannot stop finer)"))
    stop_lead_m: float = Field(default=0.02, ge=0.0, description=(
        "stop this early: IR delay x speed + the part of a step finished after stop"))
    near_m: float = Field(default=0.08, gt=0.0, description="no turning closer than this")
    settle_s: float = Field(default=0.9, ge=0.0, description="after a stop, before judging")
    correction_s: float = Field(default=0.1, ge=0.0, description=(
        "how long a correction's walk command stands before stop (one step follows)"))
    max_corrections: int = Field(default=2, ge=0,
                                 description="single steps to correct an overshoot, at most")
    uncertain_wait_s: float = Field(default=0.5, ge=0.0, description=(
        "no turn is decided on a heading whose sigma exceeds k: wait this long at most for "
        "a surer one (s)"))
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
    reason: str = ""


@dataclass
class HeuristicController:
    """Decides one command per control tick from the latest pose."""

    params: ControlParams = field(default_factory=ControlParams)
    waypoints: list[tuple[float, float]] = field(default_factory=list)
    index: int = 0
    phase: Phase = Phase.IDLE
    reversals: int = 0
    corrections: int = 0
    _since_s: float = 0.0                 # when the current settling or correction began
    _last_walk: Command | None = None
    _last_turn: Command | None = None
    _correction: Command = Command.STOP   # the walk of the correction under way
    done_reason: str = ""                 # how the last waypoint was reached
    _heading_sigma: float | None = None
    _uncertain_since: float | None = None  # waiting for a surer heading since

    def set_waypoints(self, waypoints: list[tuple[float, float]]) -> None:
        self.waypoints, self.index, self.corrections = list(waypoints), 0, 0
        self.done_reason = ""
        self.phase = Phase.IDLE if not waypoints else Phase.WAITING_POSE

    def decide(self, pose: tuple[float, float, float] | None, pose_age_s: float,
               hold: bool, now_s: float | None = None,
               heading_sigma_rad: float | None = None, stale: str = "") -> Decision:
        """One control step. ``pose`` is (x m, y m, yaw rad) in the world, or None;
        ``now_s`` a monotonic time (the simulator's in direct loops); ``heading_sigma_rad``
        the pose's heading standard deviation, when known; ``stale`` why the pose must not be
        steered by although young (e.g. held in a buffer during a network cut)."""
        now = time.monotonic() if now_s is None else now_s
        self._heading_sigma = heading_sigma_rad
        if stale and self.index < len(self.waypoints):
            self.phase = Phase.WAITING_POSE
            d = Decision(Command.STOP, Phase.WAITING_POSE, self.index, reason=stale)
        else:
            d = self._decide(pose, pose_age_s, hold, now)
        self._count_reversal(d.command)
        return d

    def _count_reversal(self, cmd: Command) -> None:
        if cmd in (Command.WALK_FORWARD, Command.WALK_BACKWARD):
            if self._last_walk is not None and cmd is not self._last_walk:
                self.reversals += 1
            self._last_walk = cmd
        elif cmd in (Command.TURN_LEFT, Command.TURN_RIGHT):
            if self._last_turn is not None and cmd is not self._last_turn:
                self.reversals += 1
            self._last_turn = cmd

    def _decide(self, pose: tuple[float, float, float] | None, pose_age_s: float,
                hold: bool, now: float) -> Decision:
        p = self.params
        if self.index >= len(self.waypoints):
            self.phase = Phase.DONE if self.waypoints else Phase.IDLE
            return Decision(Command.STOP, self.phase, self.index,
                            reason=self.done_reason if self.waypoints else "no mission")
        if pose is None or pose_age_s > p.pose_timeout_s:
            self.phase = Phase.WAITING_POSE
            why = "no pose yet" if pose is None else f"pose {1000 * pose_age_s:.0f} ms old"
            return Decision(Command.STOP, Phase.WAITING_POSE, self.index, reason=why)
        x, y, yaw = pose
        gx, gy = self.waypoints[self.index]
        e = math.hypot(gx - x, gy - y)
        alpha = wrap_angle(math.atan2(gy - y, gx - x) - yaw)
        along = e * math.cos(alpha)  # the goal's distance ahead along the heading
        if hold:
            self.phase = Phase.HOLD
            return Decision(Command.STOP, Phase.HOLD, self.index, e, alpha,
                            "held by the camera planner")
        if self.phase is Phase.CORRECTING:
            if now - self._since_s < p.correction_s:
                return Decision(self._correction, Phase.CORRECTING, self.index, e, alpha,
                                f"correction {self.corrections}: one step")
            return self._settle(now, e, alpha, "correction step under way")
        if self.phase is Phase.SETTLING:
            if now - self._since_s < p.settle_s:
                return Decision(Command.STOP, Phase.SETTLING, self.index, e, alpha,
                                "waiting for the last step to finish")
            if abs(along) <= p.goal_tolerance_m or self.corrections >= p.max_corrections:
                return self._reached(pose, hold, now, e, alpha, along)
            self.corrections += 1
            self._correction = Command.WALK_FORWARD if along > 0 else Command.WALK_BACKWARD
            self.phase, self._since_s = Phase.CORRECTING, now
            return Decision(self._correction, Phase.CORRECTING, self.index, e, alpha,
                            f"correction {self.corrections}: {100 * along:+.1f} cm to go")
        walking = self.phase is Phase.WALKING
        if e <= p.goal_tolerance_m + (p.stop_lead_m if walking else 0.0) or (
                e < p.near_m and along <= p.goal_tolerance_m + p.stop_lead_m):
            if walking:
                return self._settle(now, e, alpha, f"stopping {100 * e:.1f} cm short")
            return self._reached(pose, hold, now, e, alpha, along)
        if e >= p.near_m:
            limit = p.turn_release_rad if self.phase is Phase.TURNING else p.turn_threshold_rad
            if abs(alpha) > limit and self.phase is not Phase.TURNING and \
                    self._heading_sigma is not None and \
                    self._heading_sigma > p.turn_threshold_rad:
                if self._uncertain_since is None:
                    self._uncertain_since = now
                if now - self._uncertain_since < p.uncertain_wait_s:
                    return Decision(Command.STOP, self.phase, self.index, e, alpha,
                                    f"heading uncertain (sigma "
                                    f"{math.degrees(self._heading_sigma):.0f}° > k): waiting")
            else:
                self._uncertain_since = None
            if abs(alpha) > limit:
                self._uncertain_since = None
                self.phase = Phase.TURNING
                cmd = Command.TURN_LEFT if alpha > 0 else Command.TURN_RIGHT
                return Decision(cmd, Phase.TURNING, self.index, e, alpha,
                                f"heading {math.degrees(alpha):+.0f}° off")
        elif along < 0 and self.phase is not Phase.WALKING:  # just past it: step back
            self.phase, self._since_s = Phase.CORRECTING, now
            self.corrections += 1
            self._correction = Command.WALK_BACKWARD
            return Decision(Command.WALK_BACKWARD, Phase.CORRECTING, self.index, e, alpha,
                            f"{100 * -along:.1f} cm past the goal: one step back")
        self.phase = Phase.WALKING
        return Decision(Command.WALK_FORWARD, Phase.WALKING, self.index, e, alpha,
                        f"{100 * e:.1f} cm to go")

    def _settle(self, now: float, e: float, alpha: float, why: str) -> Decision:
        self.phase, self._since_s = Phase.SETTLING, now
        return Decision(Command.STOP, Phase.SETTLING, self.index, e, alpha, why)

    def _reached(self, pose: tuple[float, float, float], hold: bool, now: float, e: float,
                 alpha: float, along: float) -> Decision:
        self.index += 1
        self.corrections = 0
        self.phase = Phase.DONE if self.index >= len(self.waypoints) else Phase.IDLE
        why = (f"waypoint reached: {100 * e:.1f} cm off" if abs(along) <=
               self.params.goal_tolerance_m else
               f"stopped {100 * e:.1f} cm off after {self.params.max_corrections} corrections")
        if self.phase is Phase.DONE:
            self.done_reason = why
            return Decision(Command.STOP, Phase.DONE, self.index, e, alpha, why)
        return self._decide(pose, 0.0, hold, now)
