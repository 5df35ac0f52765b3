"""Shared maths and models, with no bus inside: rigid transforms (``geometry``), the camera
model and its projection (``camera``, ``projection``), the fixed mounts (``mounts``), the
world and its obstacles (``world``), and numba's cached ``njit`` (``jit``)."""

from services.core.camera import CameraModel, undistort_px
from services.core.geometry import T_floor, inv_T, make_T, quaternion_from_R, wrap_angle
from services.core.mounts import Geometry
from services.core.world import CircleObstacle, PolygonObstacle, World

__all__ = ["CameraModel", "CircleObstacle", "Geometry", "PolygonObstacle", "T_floor", "World",
           "inv_T", "make_T", "quaternion_from_R", "undistort_px", "wrap_angle"]
