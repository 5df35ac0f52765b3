"""Rigid transforms as 4x4 numpy arrays, named ``T_to_from`` (DESIGN.md, "Frames and units").

``T_world_camera`` maps camera coordinates into the world: ``p_world = T_world_camera @ p_cam``.
"""

from __future__ import annotations

import math

import numpy as np

#: Camera optical axes (x right, y down, z forward) expressed in a REP-103 base (x fwd, y left).
R_BASE_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
#: Marker axes (x right as seen from behind, y up, z out of the back) in the humanoid frame.
R_HUMANOID_MARKER = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def make_T(R: np.ndarray, t: np.ndarray | tuple[float, float, float]) -> np.ndarray:
    """4x4 homogeneous transform from a 3x3 rotation and a translation (m)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3)
    return T


def inv_T(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform."""
    R, t = T[:3, :3], T[:3, 3]
    return make_T(R.T, -R.T @ t)


def rot_z(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def T_floor(x: float, y: float, yaw: float) -> np.ndarray:
    """Transform of a robot standing on the floor at (x, y) m with heading yaw rad."""
    return make_T(rot_z(yaw), (x, y, 0.0))


def floor_pose(T_world_body: np.ndarray) -> tuple[float, float, float]:
    """(x m, y m, yaw rad) of a body frame whose x axis is its heading."""
    heading = T_world_body[:3, 0]
    return float(T_world_body[0, 3]), float(T_world_body[1, 3]), math.atan2(heading[1],
                                                                            heading[0])


def T_base_camera(forward_m: float, height_m: float, pitch_rad: float) -> np.ndarray:
    """Camera optical frame -> base: camera ``forward_m`` ahead, ``height_m`` up, pitched down."""
    return make_T(rot_y(pitch_rad) @ R_BASE_OPTICAL, (forward_m, 0.0, height_m))


def T_humanoid_marker(back_offset_m: float, height_m: float) -> np.ndarray:
    """Marker frame -> humanoid frame: marker centre ``back_offset_m`` behind, ``height_m`` up."""
    return make_T(R_HUMANOID_MARKER, (-back_offset_m, 0.0, height_m))


def wrap_angle(angle: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


def quaternion_from_R(R: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w) of a rotation matrix, w >= 0."""
    m = np.asarray(R, dtype=np.float64).tolist()  # Python floats: no numpy per element
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        w, x = 0.25 * s, (m[2][1] - m[1][2]) / s
        y, z = (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s
    elif m[0][0] > m[1][1] and m[0][0] > m[2][2]:
        s = math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2]) * 2
        w, x = (m[2][1] - m[1][2]) / s, 0.25 * s
        y, z = (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s
    elif m[1][1] > m[2][2]:
        s = math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2]) * 2
        w, x = (m[0][2] - m[2][0]) / s, (m[0][1] + m[1][0]) / s
        y, z = 0.25 * s, (m[1][2] + m[2][1]) / s
    else:
        s = math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1]) * 2
        w, x = (m[1][0] - m[0][1]) / s, (m[0][2] + m[2][0]) / s
        y, z = (m[1][2] + m[2][1]) / s, 0.25 * s
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if w < 0:
        norm = -norm
    return float(x / norm), float(y / norm), float(z / norm), float(w / norm)
