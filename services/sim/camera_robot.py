"""The wheeled camera robot: a unicycle that drives to the latest goal within limits."""

from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from services.core.geometry import wrap_angle
from services.core.world import World


class CameraRobotParams(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    max_speed_mps: float = Field(default=0.25, gt=0.0, description="top speed")
    max_accel_mps2: float = Field(default=0.5, gt=0.0, description="acceleration limit")
    max_yaw_rate_radps: float = Field(default=1.5, gt=0.0, description="turn rate limit")
    radius_m: float = Field(default=0.08, gt=0.0, description="its disc, for collisions")
    position_tolerance_m: float = Field(default=0.005, gt=0.0,
                                        description="a goal this near is reached")
    # the pose its locating system reports (the paper's camera robot has one): a constant
    # bias and white noise (estimates of a small robot's), at its own rate, late
    odom_bias: tuple[float, float, float] = Field(default=(0.003, -0.002, 0.005), description=(
        "constant error of the reported pose: x m, y m, yaw rad"))
    odom_noise_m: float = Field(default=0.001, ge=0.0, description="1-sigma white noise")
    odom_noise_rad: float = Field(default=0.002, ge=0.0,
                                  description="1-sigma white noise on the yaw")
    odom_hz: float = Field(default=20.0, gt=0.0, description="its own rate, not the frames'")
    odom_latency_s: float = Field(default=0.02, ge=0.0,
                                  description="published this long after its stamp")


class CameraRobot:
    """Pose (x m, y m, yaw rad) in the world and forward speed (m/s)."""

    def __init__(self, x: float, y: float, yaw: float,
                 params: CameraRobotParams | None = None, seed: int = 0) -> None:
        self.x, self.y, self.yaw = x, y, yaw
        self.v = 0.0
        self.params = params or CameraRobotParams()
        self.goal: tuple[float, float, float] | None = None
        self.blocked = False
        self._rng = np.random.default_rng(seed + 7919)

    def step(self, dt: float, world: World | None = None) -> None:
        """Drive towards the goal for ``dt`` seconds; never into an obstacle."""
        p = self.params
        v_target = w = 0.0
        if self.goal is not None:
            gx, gy, gyaw = self.goal
            dx, dy = gx - self.x, gy - self.y
            rho = math.hypot(dx, dy)
            if rho > p.position_tolerance_m:
                alpha = wrap_angle(math.atan2(dy, dx) - self.yaw)
                sign = 1.0
                if abs(alpha) > math.pi / 2:  # closer to back up than to turn around
                    alpha, sign = wrap_angle(alpha + math.pi), -1.0
                w = 3.0 * alpha
                v_target = sign * min(p.max_speed_mps, 1.5 * rho) * max(0.0, math.cos(alpha))
            else:
                w = 3.0 * wrap_angle(gyaw - self.yaw)
        w = max(-p.max_yaw_rate_radps, min(p.max_yaw_rate_radps, w))
        dv = max(-p.max_accel_mps2 * dt, min(p.max_accel_mps2 * dt, v_target - self.v))
        self.v += dv
        nx = self.x + self.v * dt * math.cos(self.yaw)
        ny = self.y + self.v * dt * math.sin(self.yaw)
        self.blocked = world is not None and world.collides(nx, ny, p.radius_m)
        if self.blocked:
            self.v = 0.0
        else:
            self.x, self.y = nx, ny
        self.yaw = wrap_angle(self.yaw + w * dt)

    def odometry(self) -> tuple[float, float, float]:
        """The pose as the robot's locating system reports it: its bias and white noise."""
        p = self.params
        n = self._rng.standard_normal(3)
        bx, by, byaw = p.odom_bias
        return (self.x + bx + p.odom_noise_m * n[0], self.y + by + p.odom_noise_m * n[1],
                wrap_angle(self.yaw + byaw + p.odom_noise_rad * n[2]))
