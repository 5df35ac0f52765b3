"""Shepherd messages to and from ROS 2 messages (rosbags' classes; no Zenoh inside).

Frames are named by the caller (``frames.Tree``); stamps to the nanosecond; angles in rad;
metres.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from schemas import CameraGoal, CameraIntrinsics, CameraPose, HumanoidPose, MissionGoal
from services.core.geometry import quaternion_from_R
from services.ros2_bridge.frames import Tree, UnknownFrameError
from services.ros2_bridge.rmw import typestore

POSE_COV = "geometry_msgs/msg/PoseWithCovarianceStamped"
POSE = "geometry_msgs/msg/PoseStamped"
TF = "tf2_msgs/msg/TFMessage"
ODOMETRY = "nav_msgs/msg/Odometry"
IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
LOG = "rcl_interfaces/msg/Log"
#: variance given to z, roll and pitch of a floor pose (fixed by the floor: tiny, not zero,
#: so that viewers can invert the matrix)
FLOOR_VARIANCE = 1e-9
# indices of x, y and yaw in a 6 x 6 pose covariance (x, y, z, rot x, rot y, rot z)
_XY_YAW = (0, 1, 5)


def _t(name: str) -> Any:
    return typestore().types[name]


def stamp(stamp_ns: int) -> Any:
    """builtin_interfaces/Time of a Unix time in ns."""
    return _t("builtin_interfaces/msg/Time")(sec=stamp_ns // 1_000_000_000,
                                              nanosec=stamp_ns % 1_000_000_000)


def stamp_ns(time: Any) -> int:
    return int(time.sec) * 1_000_000_000 + int(time.nanosec)


def header(stamp_ns_: int, frame_id: str) -> Any:
    return _t("std_msgs/msg/Header")(stamp=stamp(stamp_ns_), frame_id=frame_id)


def yaw_quaternion(yaw: float) -> Any:
    return _t("geometry_msgs/msg/Quaternion")(x=0.0, y=0.0, z=math.sin(yaw / 2),
                                              w=math.cos(yaw / 2))


def quaternion_yaw(q: Any) -> float:
    """Heading (rad about z) of a quaternion."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _pose(x: float, y: float, yaw: float) -> Any:
    return _t("geometry_msgs/msg/Pose")(position=_t("geometry_msgs/msg/Point")(x=x, y=y, z=0.0),
                                        orientation=yaw_quaternion(yaw))


def floor_covariance_6(cov3: np.ndarray | None) -> np.ndarray:
    """The 6 x 6 covariance (row-major, 36) of a floor pose with 3 x 3 ``cov3`` over
    (x, y, yaw); z, roll and pitch get ``FLOOR_VARIANCE``. Unknown ``cov3``: -1 first, as
    REP-103 viewers read "unknown"."""
    out = np.zeros((6, 6))
    if cov3 is None:
        out[0, 0] = -1.0
        return out.reshape(36)
    for i, a in enumerate(_XY_YAW):
        for j, b in enumerate(_XY_YAW):
            out[a, b] = cov3[i, j]
    for k in (2, 3, 4):
        out[k, k] = FLOOR_VARIANCE
    return out.reshape(36)


def humanoid_pose(msg: HumanoidPose, world_frame: str) -> Any | None:
    """PoseWithCovarianceStamped of the humanoid (None while its world pose is unknown)."""
    if msg.x is None or msg.y is None or msg.yaw is None:
        return None
    cov = np.array(msg.covariance) if msg.covariance is not None else None
    return _t(POSE_COV)(header=header(msg.stamp_ns, world_frame), pose=_t(
        "geometry_msgs/msg/PoseWithCovariance")(pose=_pose(msg.x, msg.y, msg.yaw),
                                                covariance=floor_covariance_6(cov)))


def transform(stamp_ns_: int, parent: str, child: str, x: float, y: float, yaw: float) -> Any:
    return _t("geometry_msgs/msg/TransformStamped")(
        header=header(stamp_ns_, parent), child_frame_id=child,
        transform=_t("geometry_msgs/msg/Transform")(
            translation=_t("geometry_msgs/msg/Vector3")(x=x, y=y, z=0.0),
            rotation=yaw_quaternion(yaw)))


def transform_T(stamp_ns_: int, parent: str, child: str, T_parent_child: np.ndarray) -> Any:
    """TransformStamped of a 4x4 rigid transform (the child's pose in the parent)."""
    x, y, z, w = quaternion_from_R(T_parent_child[:3, :3])
    tx, ty, tz = (float(v) for v in T_parent_child[:3, 3])
    return _t("geometry_msgs/msg/TransformStamped")(
        header=header(stamp_ns_, parent), child_frame_id=child,
        transform=_t("geometry_msgs/msg/Transform")(
            translation=_t("geometry_msgs/msg/Vector3")(x=tx, y=ty, z=tz),
            rotation=_t("geometry_msgs/msg/Quaternion")(x=x, y=y, z=z, w=w)))


def tf_message(transforms: list[Any]) -> Any:
    return _t(TF)(transforms=transforms)


def camera_goal(msg: CameraGoal, tree: Tree, goal_frame: str) -> Any:
    """PoseStamped of where the camera robot should stand (e.g. for Nav2's /goal_pose),
    expressed in ``goal_frame`` (UnknownFrameError if the tree cannot reach it)."""
    x, y, yaw = tree.from_world(goal_frame, (msg.x, msg.y, msg.yaw))
    return _t(POSE)(header=header(msg.stamp_ns, goal_frame), pose=_pose(x, y, yaw))


def _floor(pose: Any) -> tuple[float, float, float]:
    return (float(pose.position.x), float(pose.position.y), quaternion_yaw(pose.orientation))


def odometry_to_camera_pose(odom: Any, tree: Tree) -> CameraPose:
    """``camera/odom`` from a nav_msgs/Odometry: its pose, in its header's frame, moved into
    the world (UnknownFrameError, naming it, for a frame the tree cannot reach, or for a
    ``child_frame_id`` other than the camera robot's base: odometry of another body)."""
    child = str(odom.child_frame_id)
    if child and child != tree.names.base:
        raise UnknownFrameError(
            f"odometry of {child!r}, not of the camera robot's base {tree.names.base!r}: set "
            f"[services.ros2_bridge] base_frame = {child!r} if that is the robot's base")
    x, y, yaw = tree.to_world(odom.header.frame_id, _floor(odom.pose.pose))
    return CameraPose(stamp_ns=stamp_ns(odom.header.stamp), x=x, y=y, yaw=yaw)


def pose_to_mission_goal(pose: Any, tree: Tree) -> MissionGoal:
    """A PoseStamped goal (its position, moved into the world from its header's frame) as a
    one-waypoint mission; UnknownFrameError for a frame the tree cannot reach."""
    x, y, _ = tree.to_world(pose.header.frame_id, _floor(pose.pose))
    return MissionGoal(stamp_ns=stamp_ns(pose.header.stamp), waypoints=[(x, y)])


def compressed_image(jpeg: bytes, stamp_ns_: int, frame_id: str) -> Any:
    return _t(IMAGE)(header=header(stamp_ns_, frame_id), format="jpeg",
                     data=np.frombuffer(jpeg, np.uint8))


def camera_info(k: CameraIntrinsics, stamp_ns_: int, frame_id: str) -> Any:
    """sensor_msgs/CameraInfo of the intrinsics (plumb_bob; skew kept in K, P without it)."""
    K = np.array(k.K, dtype=np.float64)
    P = np.zeros((3, 4))
    P[:, :3] = K
    return _t(CAMERA_INFO)(
        header=header(stamp_ns_, frame_id), height=k.height, width=k.width,
        distortion_model="plumb_bob", d=np.array(k.dist, dtype=np.float64),
        k=K.reshape(9), r=np.eye(3).reshape(9), p=P.reshape(12), binning_x=0, binning_y=0,
        roi=_t("sensor_msgs/msg/RegionOfInterest")(x_offset=0, y_offset=0, height=0, width=0,
                                                   do_rectify=False))


def log_message(record: logging.LogRecord) -> Any:
    """rcl_interfaces/Log of a Python log record (its levels are ROS's: 10 DEBUG ... 50 FATAL)."""
    return _t(LOG)(stamp=stamp(int(record.created * 1e9)),
                   level=min(50, max(10, record.levelno // 10 * 10)), name=record.name,
                   msg=record.getMessage(), file=record.pathname, function=record.funcName,
                   line=record.lineno)
