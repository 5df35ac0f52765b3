"""Where the camera robot should stand (paper section 6), on the floor plane (world, m).

Aim: the camera's optical centre at distance d from the marker, on the current line of sight,
facing the marker (so the rhombus centre is at the image centre). When the view is more than
``90 deg - theta`` off the marker's normal (theta, the critical angle between the humanoid's
lateral axis and the optical axis), the humanoid is held and the camera goes to P_D, straight
behind the humanoid at distance d; the hold is released once the view is within
``release_rad`` of the normal. A goal in collision (obstacles, or the humanoid itself) becomes
the nearest free pose, preferring poses that still see the marker within the critical angle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from services.core.geometry import wrap_angle
from services.core.mounts import Geometry
from services.core.world import World


class PlannerParams(BaseModel):
    """The planner's parameters (the service's settings are these plus its loop's); the only
    place their defaults are defined. The mounts come from the deployment's geometry."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    distance_m: float = Field(default=0.25, gt=0.0,
                              description="d: optical centre to marker centre (m)")
    critical_angle_deg: float = Field(default=50.0, gt=0.0, lt=90.0, description="theta")
    release_deg: float = Field(default=15.0, ge=0.0, lt=90.0,
                               description="a hold is released below this view angle")
    robot_radius_m: float = Field(default=0.08, gt=0.0, description="the camera robot's disc")
    humanoid_radius_m: float = Field(default=0.09, gt=0.0, description="the humanoid's disc")
    clearance_m: float = Field(default=0.02, ge=0.0, description="kept from obstacles")

    @property
    def critical_angle_rad(self) -> float:
        return math.radians(self.critical_angle_deg)

    @property
    def release_rad(self) -> float:
        return math.radians(self.release_deg)


@dataclass(frozen=True)
class Plan:
    goal: tuple[float, float, float]   # base x m, y m, yaw rad
    hold: bool
    view_angle_rad: float              # angle between the line of sight and the marker normal
    reason: str


@dataclass
class CameraPlanner:
    params: PlannerParams = field(default_factory=PlannerParams)
    world: World = field(default_factory=World)
    mounts: Geometry = field(default_factory=Geometry)
    holding: bool = False

    def marker_centre(self, humanoid: tuple[float, float, float]) -> np.ndarray:
        x, y, yaw = humanoid
        b = self.mounts.marker_back_offset_m
        return np.array([x - b * math.cos(yaw), y - b * math.sin(yaw)])

    def view_angle(self, humanoid: tuple[float, float, float],
                   camera: tuple[float, float, float]) -> float:
        """Angle (rad) between the marker's normal and the direction to the camera."""
        m = self.marker_centre(humanoid)
        c = self._optical_centre(camera)
        normal = -np.array([math.cos(humanoid[2]), math.sin(humanoid[2])])
        d = c - m
        n = float(np.linalg.norm(d))
        if n < 1e-9:
            return 0.0
        return math.acos(max(-1.0, min(1.0, float(normal @ d) / n)))

    def _optical_centre(self, base: tuple[float, float, float]) -> np.ndarray:
        f = self.mounts.camera_forward_m
        return np.array([base[0] + f * math.cos(base[2]), base[1] + f * math.sin(base[2])])

    def _base_for(self, optical: np.ndarray, marker: np.ndarray) -> tuple[float, float, float]:
        yaw = math.atan2(marker[1] - optical[1], marker[0] - optical[0])
        f = self.mounts.camera_forward_m
        return (float(optical[0] - f * math.cos(yaw)), float(optical[1] - f * math.sin(yaw)),
                yaw)

    def _free(self, base: tuple[float, float, float], humanoid: tuple[float, float, float]
              ) -> bool:
        p = self.params
        r = p.robot_radius_m + p.clearance_m
        if math.hypot(base[0] - humanoid[0], base[1] - humanoid[1]) < r + p.humanoid_radius_m:
            return False
        return not self.world.collides(base[0], base[1], r)

    def plan(self, humanoid: tuple[float, float, float],
             camera: tuple[float, float, float]) -> Plan:
        """The goal for the camera base, and whether the humanoid must hold still."""
        p = self.params
        m = self.marker_centre(humanoid)
        normal = -np.array([math.cos(humanoid[2]), math.sin(humanoid[2])])
        angle = self.view_angle(humanoid, camera)
        limit = math.pi / 2 - p.critical_angle_rad
        if angle > limit:
            self.holding = True
        elif self.holding and angle < p.release_rad:
            self.holding = False
        if self.holding:
            direction, reason = normal, "critical angle: to P_D behind the humanoid"
        else:
            d = self._optical_centre(camera) - m
            n = float(np.linalg.norm(d))
            direction = d / n if n > 1e-9 else normal
            reason = "follow at distance d"
        goal = self._base_for(m + p.distance_m * direction, m)
        if self._free(goal, humanoid):
            return Plan(goal, self.holding, angle, reason)
        alt = self._nearest_free(goal, m, normal, humanoid)
        if alt is None:  # boxed in: stay put and hold the humanoid
            return Plan(camera, True, angle, "no free pose near the goal: stay and hold")
        return Plan(alt, self.holding, angle, reason + "; goal blocked, nearest free pose")

    def _nearest_free(self, goal: tuple[float, float, float], m: np.ndarray,
                      normal: np.ndarray, humanoid: tuple[float, float, float]
                      ) -> tuple[float, float, float] | None:
        p = self.params
        limit = math.pi / 2 - p.critical_angle_rad
        base_angle = math.atan2(normal[1], normal[0])
        best: tuple[tuple[int, float], tuple[float, float, float]] | None = None
        for radius in p.distance_m + np.arange(0.0, 0.6, 0.025):
            for a in np.radians(np.arange(-180, 180, 5)):
                direction = np.array([math.cos(base_angle + a), math.sin(base_angle + a)])
                cand = self._base_for(m + radius * direction, m)
                if not self._free(cand, humanoid):
                    continue
                sees = abs(wrap_angle(a)) <= limit
                cost = (0 if sees else 1, math.hypot(cand[0] - goal[0], cand[1] - goal[1]))
                if best is None or cost < best[0]:
                    best = (cost, cand)
        return None if best is None else best[1]
