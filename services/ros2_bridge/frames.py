"""The bridge's TF tree (REP-105, REP-103) and floor poses between its frames (no Zenoh).

The tree a ROS 2 user sees (default names)::

    map ─┬─ odom ── base_link ── camera_link ── camera_optical_frame
         └─ humanoid

- ``map`` -> ``odom``: static, Shepherd's ``T_world_odom`` (Shepherd's world is ``map``).
- ``odom`` -> ``base_link``: the camera robot's own odometry, published by the robot (never by
  the bridge: one publisher per transform).
- ``base_link`` -> ``camera_link`` -> ``camera_optical_frame``: static, the deployment's
  ``[geometry]`` mount (``camera_link`` a REP-103 body frame pitched down,
  ``camera_optical_frame`` x right, y down, z forward).
- ``map`` -> ``humanoid``: dynamic, the estimated humanoid pose.

A floor pose (x m, y m, yaw rad) is carried between ``map`` and ``odom`` only: those are the
frames the bridge knows at every instant; any other frame is refused with its name.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.core.geometry import R_BASE_OPTICAL, T_floor, floor_pose, inv_T, make_T, rot_y
from services.core.mounts import Geometry

#: (x m, y m, yaw rad) of a pose on the floor
FloorPose = tuple[float, float, float]


class UnknownFrameError(ValueError):
    """A message in a frame the bridge cannot reach; the text names the frame."""


@dataclass(frozen=True)
class FrameNames:
    """The names the ROS side uses (REP-105 defaults, as Nav2 has them)."""

    world: str = "map"
    odom: str = "odom"
    base: str = "base_link"
    camera: str = "camera_link"
    optical: str = "camera_optical_frame"
    humanoid: str = "humanoid"

    def check(self) -> None:
        """Raises ValueError unless every frame has its own non-empty name."""
        names = [self.world, self.odom, self.base, self.camera, self.optical, self.humanoid]
        if any(not n or n.startswith("/") for n in names):
            raise ValueError(f"frame names must be non-empty without a leading '/': {names}")
        if len(set(names)) != len(names):
            raise ValueError(f"each frame needs its own name (one TF tree, one parent per "
                             f"frame), got {names}")


@dataclass(frozen=True)
class Tree:
    """The frames the bridge knows: names, the odometry frame in the world, the camera mount."""

    names: FrameNames
    T_world_odom: FloorPose
    geometry: Geometry

    def static_transforms(self) -> list[tuple[str, str, np.ndarray]]:
        """(parent, child, 4x4 T_parent_child) the bridge publishes on /tf_static."""
        n, g = self.names, self.geometry
        T_base_camera_link = make_T(rot_y(g.camera_pitch_rad),
                                    (g.camera_forward_m, 0.0, g.camera_height_m))
        return [(n.world, n.odom, T_floor(*self.T_world_odom)),
                (n.base, n.camera, T_base_camera_link),
                (n.camera, n.optical, make_T(R_BASE_OPTICAL, (0.0, 0.0, 0.0)))]

    def _T_world(self, frame: str) -> np.ndarray:
        if frame == self.names.world:
            return np.eye(4)
        if frame == self.names.odom:
            return T_floor(*self.T_world_odom)
        raise UnknownFrameError(
            f"frame {frame!r} is not one the bridge can reach: it takes poses in "
            f"{self.names.world!r} (Shepherd's world) or {self.names.odom!r} "
            f"(T_world_odom)" if frame else
            f"no frame_id: the bridge takes poses in {self.names.world!r} or "
            f"{self.names.odom!r}")

    def to_world(self, frame: str, pose: FloorPose) -> FloorPose:
        """``pose`` given in ``frame`` as a world pose; UnknownFrameError for other frames."""
        return floor_pose(self._T_world(frame) @ T_floor(*pose))

    def from_world(self, frame: str, pose: FloorPose) -> FloorPose:
        """A world pose expressed in ``frame``; UnknownFrameError for other frames."""
        return floor_pose(inv_T(self._T_world(frame)) @ T_floor(*pose))
