"""The simulated world's state, stepped in simulated time (no bus inside)."""

from __future__ import annotations

import numpy as np

from schemas import Command
from services.core.camera import CameraModel
from services.core.geometry import T_floor, inv_T, make_T, rot_z
from services.core.mounts import Geometry
from services.core.world import World
from services.sim.camera_robot import CameraRobot, CameraRobotParams
from services.sim.humanoid import Humanoid, HumanoidParams
from services.sim.render import Rendered, RenderStyle, render_view


class SimWorld:
    """Humanoid, camera robot and obstacles; renders what the camera sees."""

    def __init__(self, *, camera: CameraModel, geometry: Geometry, world: World,
                 humanoid_start: tuple[float, float, float],
                 camera_start: tuple[float, float, float],
                 humanoid: HumanoidParams | None = None,
                 camera_robot: CameraRobotParams | None = None,
                 style: RenderStyle | None = None, seed: int = 0) -> None:
        self.camera, self.geometry, self.world = camera, geometry, world
        self.humanoid = Humanoid(*humanoid_start, params=humanoid, seed=seed)
        self.robot = CameraRobot(*camera_start, params=camera_robot, seed=seed)
        self.style = style or RenderStyle(seed=seed)
        self.time_s = 0.0
        self.frame_index = 0
        self._marker_points = geometry.marker_points()
        self._T_base_camera = geometry.T_base_camera()
        self._T_humanoid_marker = geometry.T_humanoid_marker()

    def command(self, command: Command) -> None:
        self.humanoid.receive(command)

    def step(self, dt: float) -> None:
        self.time_s += dt
        self.humanoid.step(dt, self.world)
        self.robot.step(dt, self.world)

    def T_world_camera(self) -> np.ndarray:
        r = self.robot
        return T_floor(r.x, r.y, r.yaw) @ self._T_base_camera

    def T_world_humanoid(self) -> np.ndarray:
        h = self.humanoid
        return T_floor(h.x, h.y, h.yaw)

    def T_camera_marker(self) -> np.ndarray:
        sway = make_T(rot_z(self.humanoid.sway()), (0.0, 0.0, 0.0))  # roll about the normal
        return (inv_T(self.T_world_camera()) @ self.T_world_humanoid() @ self._T_humanoid_marker
                @ sway)

    def render(self) -> Rendered:
        T_camera_humanoid = inv_T(self.T_world_camera()) @ self.T_world_humanoid()
        out = render_view(self.camera, self.T_camera_marker(), marker_points_m=self._marker_points,
                          T_camera_humanoid=T_camera_humanoid, style=self.style,
                          frame_index=self.frame_index)
        self.frame_index += 1
        return out

