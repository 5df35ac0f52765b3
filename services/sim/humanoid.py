"""A Robosapien V1 as it walks, driven by IR commands on the floor plane.

Its walk is static (paper section 5): discrete steps. A walking step carries the body one
``step_length_m`` forward (or ``back_step_length_m`` backward) in ``step_period_s``, along a
smooth profile, the torso rocking sideways over the stance foot and back (alternating each
step), so the marker on its back moves across the path while the feet's path stays smooth;
each step's length slips and its heading drifts a little. A turn is made of discrete turning
steps of ``turn_step_deg``. A command takes effect after ``reaction_delay_s``; a new command
(``stop`` included) waits for the current step to finish, as the toy's does.

The defaults are estimates, not published figures: WowWee's manual and product pages give no
speed, stride or turn rate, and none was found in the literature available here. A stride of
4 cm every 0.6 s (6.7 cm/s), 12° turning steps at 30°/s, a 1.1° rock (4 mm at the marker)
and a 0.15 s IR
reaction delay match footage of the toy's gait as well as we could judge; all are settings.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from schemas import Command
from services.core.geometry import wrap_angle
from services.core.world import World


class HumanoidParams(BaseModel):
    """The simulated gait (estimates; see the module's docstring). Metres, seconds, degrees."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    step_length_m: float = Field(default=0.04, ge=0.0, description="forward stride")
    back_step_length_m: float = Field(default=0.03, ge=0.0, description="backward stride")
    step_period_s: float = Field(default=0.6, gt=0.0, description="one walking step")
    turn_step_deg: float = Field(default=12.0, ge=0.0, description="one turning step")
    turn_period_s: float = Field(default=0.4, gt=0.0, description="one turning step")
    reaction_delay_s: float = Field(default=0.15, ge=0.0, description="IR to first motion")
    slip_fraction: float = Field(default=0.08, ge=0.0, description="1-sigma stride noise")
    heading_drift_deg: float = Field(default=0.8, ge=0.0,
                                     description="1-sigma heading change per walking step")
    turn_noise_fraction: float = Field(default=0.1, ge=0.0,
                                       description="1-sigma noise of a turning step")
    sway_m: float = Field(default=0.0, ge=0.0, description=(
        "the body origin's sideways shift in a step (the toy mostly rocks about its feet)"))
    sway_rad: float = Field(default=0.02, ge=0.0, description=(
        "the torso's roll in a step: the marker, 20 cm up, moves 4 mm sideways"))
    radius_m: float = Field(default=0.09, gt=0.0, description="its disc, for collisions")


@dataclass
class _Step:
    """One step under way: where it started and where it goes."""

    command: Command
    start: tuple[float, float, float]
    advance_m: float      # along the starting heading (negative: backward)
    turn_rad: float
    duration_s: float
    side: float           # +1 sway to the left, -1 to the right
    elapsed_s: float = 0.0

    @property
    def progress(self) -> float:
        return min(1.0, self.elapsed_s / self.duration_s)


class Humanoid:
    """State (x m, y m, yaw rad) in the world; ``step`` advances the gait."""

    def __init__(self, x: float, y: float, yaw: float, params: HumanoidParams | None = None,
                 seed: int = 0) -> None:
        self.x, self.y, self.yaw = x, y, yaw
        self.params = params or HumanoidParams()
        self.command = Command.STOP   # what it was last told (after the reaction delay)
        self._pending: deque[tuple[float, Command]] = deque(maxlen=64)
        self._rng = np.random.default_rng(seed)
        self._step: _Step | None = None
        self._side = 1.0
        self.time_s = 0.0
        self.steps = 0

    def receive(self, command: Command, at_s: float | None = None) -> None:
        """An IR command arrives; it takes effect after the reaction delay."""
        t = self.time_s if at_s is None else at_s
        self._pending.append((t + self.params.reaction_delay_s, command))

    @property
    def moving(self) -> bool:
        return self._step is not None

    def step(self, dt: float, world: World | None = None) -> None:
        """Advance ``dt`` seconds."""
        self.time_s += dt
        while self._pending and self._pending[0][0] <= self.time_s:
            self.command = self._pending.popleft()[1]
        left = dt
        while left > 1e-12:
            if self._step is None:
                self._step = self._begin(world)
                if self._step is None:
                    return
            take = min(left, self._step.duration_s - self._step.elapsed_s)
            self._step.elapsed_s += take
            left -= take
            self._place(self._step)
            if self._step.elapsed_s >= self._step.duration_s - 1e-12:
                self._step = None  # done: the next starts from the current command
                self.steps += 1

    def _begin(self, world: World | None) -> _Step | None:
        p, rng, c = self.params, self._rng, self.command
        start = (self.x, self.y, self.yaw)
        if c in (Command.WALK_FORWARD, Command.WALK_BACKWARD):
            length = p.step_length_m if c is Command.WALK_FORWARD else -p.back_step_length_m
            length *= 1.0 + p.slip_fraction * rng.standard_normal()
            turn = math.radians(p.heading_drift_deg) * rng.standard_normal()
            end_x = self.x + length * math.cos(self.yaw)
            end_y = self.y + length * math.sin(self.yaw)
            if world is not None and world.collides(end_x, end_y, p.radius_m):
                length = 0.0  # blocked: it steps on the spot
            self._side = -self._side
            return _Step(c, start, length, turn, p.step_period_s, self._side)
        if c in (Command.TURN_LEFT, Command.TURN_RIGHT):
            angle = math.radians(p.turn_step_deg) * (1.0 + p.turn_noise_fraction
                                                     * rng.standard_normal())
            return _Step(c, start, 0.0, angle if c is Command.TURN_LEFT else -angle,
                         p.turn_period_s, 0.0)
        return None

    def _place(self, s: _Step) -> None:
        """The body along a step: smooth advance and turn, sideways sway out and back."""
        f = s.progress
        ease = 0.5 - 0.5 * math.cos(math.pi * f)
        x0, y0, yaw0 = s.start
        lateral = s.side * self.params.sway_m * math.sin(math.pi * f)
        c, sn = math.cos(yaw0), math.sin(yaw0)
        self.x = x0 + ease * s.advance_m * c - lateral * sn
        self.y = y0 + ease * s.advance_m * sn + lateral * c
        self.yaw = wrap_angle(yaw0 + ease * s.turn_rad)

    def sway(self) -> float:
        """Marker roll (rad) from the static gait's side-to-side sway."""
        s = self._step
        if s is None or s.side == 0.0:
            return 0.0
        return s.side * self.params.sway_rad * math.sin(math.pi * s.progress)
