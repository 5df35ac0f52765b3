"""A Robosapien V1 model driven by IR commands on the floor plane.

Walk forward / backward continue until ``stop`` or another command; turns are in place.

Default speeds are estimates, not published figures: WowWee's Robosapien V1 manual and product
pages give no walking speed or turn rate, and none was found in the literature available
here. The paper's Fig. 9 shows the robot covering about 30 cm in one experiment without a time
scale. We take 7 cm/s forward, 5 cm/s backward and 35 deg/s turning (typical of footage of the
toy's fast gait) with a 0.15 s IR reaction delay; all are configurable.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from schemas import Command
from services.core.geometry import wrap_angle
from services.core.world import World


class HumanoidParams(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    forward_speed_mps: float = Field(default=0.07, ge=0.0)
    backward_speed_mps: float = Field(default=0.05, ge=0.0)
    turn_rate_radps: float = Field(default=math.radians(35.0), ge=0.0)
    reaction_delay_s: float = Field(default=0.15, ge=0.0)
    slip_fraction: float = Field(default=0.08, ge=0.0, description="1-sigma speed noise")
    heading_noise_radps: float = Field(default=0.03, ge=0.0, description="1-sigma drift")
    sway_rad: float = Field(default=0.02, ge=0.0, description="marker roll amplitude in gait")
    step_period_s: float = Field(default=0.6, gt=0.0)
    radius_m: float = Field(default=0.09, gt=0.0)


class Humanoid:
    """State (x m, y m, yaw rad) in the world; ``step`` integrates the current command."""

    def __init__(self, x: float, y: float, yaw: float, params: HumanoidParams | None = None,
                 seed: int = 0) -> None:
        self.x, self.y, self.yaw = x, y, yaw
        self.params = params or HumanoidParams()
        self.command = Command.STOP
        self._pending: deque[tuple[float, Command]] = deque(maxlen=64)
        self._rng = np.random.default_rng(seed)
        self.time_s = 0.0
        self._gait_phase = 0.0

    def receive(self, command: Command, at_s: float | None = None) -> None:
        """An IR command arrives; it takes effect after the reaction delay."""
        t = self.time_s if at_s is None else at_s
        self._pending.append((t + self.params.reaction_delay_s, command))

    def step(self, dt: float, world: World | None = None) -> None:
        """Advance ``dt`` seconds."""
        p = self.params
        self.time_s += dt
        while self._pending and self._pending[0][0] <= self.time_s:
            self.command = self._pending.popleft()[1]
        v = w = 0.0
        if self.command is Command.WALK_FORWARD:
            v = p.forward_speed_mps
        elif self.command is Command.WALK_BACKWARD:
            v = -p.backward_speed_mps
        elif self.command is Command.TURN_LEFT:
            w = p.turn_rate_radps
        elif self.command is Command.TURN_RIGHT:
            w = -p.turn_rate_radps
        moving = v != 0.0 or w != 0.0
        if moving:
            v *= 1.0 + p.slip_fraction * self._rng.standard_normal()
            w += p.heading_noise_radps * self._rng.standard_normal()
            self._gait_phase += dt / p.step_period_s
        nx = self.x + v * dt * math.cos(self.yaw)
        ny = self.y + v * dt * math.sin(self.yaw)
        if world is None or not world.collides(nx, ny, p.radius_m):
            self.x, self.y = nx, ny
        self.yaw = wrap_angle(self.yaw + w * dt)

    def sway(self) -> float:
        """Marker roll (rad) from the static gait's side-to-side sway."""
        if self.command is Command.STOP:
            return 0.0
        return self.params.sway_rad * math.sin(2 * math.pi * self._gait_phase)
