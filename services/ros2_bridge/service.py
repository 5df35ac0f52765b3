"""The ``ros2_bridge`` service: Shepherd's poses, transforms and camera goals out to ROS 2 nodes
on Zenoh (rmw_zenoh), their odometry (and optionally goals) in; no ROS installation needed.

Out: ``humanoid/pose`` as PoseWithCovarianceStamped, ``/tf`` (world -> humanoid, world ->
camera base), ``camera/goal`` as PoseStamped on ``goal_topic`` (``/goal_pose`` drives Nav2),
optionally the camera image (CompressedImage) and its CameraInfo, rate-limited. In:
nav_msgs/Odometry on ``odom_topic`` -> ``camera/odom``; a PoseStamped on
``mission_goal_topic`` -> ``mission/goal``. Every endpoint is announced with rmw_zenoh's
liveliness tokens, so ``ros2 node list``, ``ros2 topic list`` and rviz2 see it.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from typing import Any, Literal

import cv2
from pydantic import Field

from schemas import CameraGoal, CameraIntrinsics, CameraPose, FrameEncoding, HumanoidPose
from schemas.keys import CAMERA_GOAL, HUMANOID_POSE, INTRINSICS, MISSION_GOAL, ODOM
from services.ros2_bridge import convert, rmw
from services.runtime.bus import Bus
from services.runtime.clock import Ticker
from services.runtime.config import ServiceSettings
from services.runtime.context import ServiceContext


class Settings(ServiceSettings):
    domain_id: int = Field(default=0, ge=0, le=232, description="ROS_DOMAIN_ID")
    node: str = Field(default="shepherd_bridge", pattern=r"^[A-Za-z][A-Za-z0-9_]*$",
                      description="the ROS 2 node name")
    type_hash: bool = Field(default=True, description="false for Humble (no type hashes)")
    world_frame: str = Field(default="world", description="the frame poses are given in")
    humanoid_frame: str = Field(default="humanoid", description="its child frame on /tf")
    camera_frame: str = Field(default="camera_base", description="the camera robot's base")
    pose_topic: str | None = Field(default=None, description="default /<namespace>/humanoid/pose")
    goal_topic: str | None = Field(default=None, description=(
        "default /<namespace>/camera/goal; /goal_pose sends it to Nav2"))
    odom_topic: str = Field(default="/odom", description="nav_msgs/Odometry in: camera/odom")
    T_world_odom: tuple[float, float, float] = Field(default=(0.0, 0.0, 0.0), description=(
        "the odometry frame in the world: x m, y m, yaw rad"))
    mission_goal_topic: str | None = Field(default=None, description=(
        "a PoseStamped here becomes mission/goal (e.g. /shepherd/mission/goal)"))
    image: bool = Field(default=False, description="also publish the camera's image + info")
    image_hz: float = Field(default=5.0, gt=0.0, le=60.0, description="image rate out")
    image_jpeg_quality: int = Field(default=80, ge=10, le=100, description="of the image")


@dataclass
class RosPublisher:
    """One ROS 2 topic we publish: its Zenoh publisher, GID and sequence numbers."""

    publisher: Any
    ros_type: str
    gid: bytes = field(default_factory=lambda: os.urandom(16))
    sequence: int = 0

    def publish(self, message: Any) -> None:
        self.sequence += 1
        self.publisher.put(rmw.serialize(message, self.ros_type),
                           attachment=rmw.pack_attachment(self.sequence, time.time_ns(),
                                                          self.gid))


@dataclass
class RosNode:
    """The bridge as a ROS 2 node: its tokens, publishers and subscriptions on a Bus."""

    bus: Bus
    config: Settings
    zid: str
    entities: int = 0

    def __post_init__(self) -> None:
        self.bus.declare_token(rmw.node_token(self.config.domain_id, self.zid, 0,
                                              self.config.node))

    def _announce(self, kind: Literal["MP", "MS"], topic: str, ros_type: str,
                  qos: rmw.Qos) -> str:
        self.entities += 1
        c = self.config
        self.bus.declare_token(rmw.entity_token(c.domain_id, self.zid, 0, self.entities, kind,
                                                c.node, topic, ros_type, qos,
                                                with_hash=c.type_hash))
        return rmw.data_key(c.domain_id, topic, ros_type, c.type_hash)

    def publisher(self, topic: str, ros_type: str, depth: int = 10) -> RosPublisher:
        key = self._announce("MP", topic, ros_type, rmw.Qos(depth=depth))
        return RosPublisher(self.bus.raw_publisher(key), ros_type)

    def subscription(self, topic: str, ros_type: str, depth: int = 10) -> Any:
        """Samples of ``topic`` from any publisher of its type (any hash: Humble's too)."""
        key = self._announce("MS", topic, ros_type, rmw.Qos(depth=depth))
        return self.bus.subscribe_raw(key.rsplit("/", 1)[0] + "/*", queue=depth)


async def main(ctx: ServiceContext, config: Settings) -> None:
    bus, log = ctx.bus, ctx.log
    ns = ctx.deployment.namespace
    node = RosNode(bus, config, str(bus.session.info.zid()))
    pose_out = node.publisher(config.pose_topic or f"/{ns}/humanoid/pose", convert.POSE_COV)
    tf_out = node.publisher("/tf", convert.TF, depth=100)
    goal_out = node.publisher(config.goal_topic or f"/{ns}/camera/goal", convert.POSE)
    odom_in = node.subscription(config.odom_topic, convert.ODOMETRY)
    goal_in = (node.subscription(config.mission_goal_topic, convert.POSE)
               if config.mission_goal_topic else None)
    poses = bus.subscribe(HUMANOID_POSE, HumanoidPose, latest=True)
    goals = bus.subscribe(CAMERA_GOAL, CameraGoal, latest=True)
    odoms = bus.subscribe(ODOM, CameraPose, latest=True)
    image_out = info_out = None
    frames = intrinsics = None
    if config.image:
        image_out = node.publisher(f"/{ns}/camera/image/compressed", convert.IMAGE, depth=1)
        info_out = node.publisher(f"/{ns}/camera/camera_info", convert.CAMERA_INFO, depth=1)
        frames = bus.subscribe_frames()
        intrinsics = bus.subscribe(INTRINSICS, CameraIntrinsics, latest=True)
    log.info("ROS 2 node %s on domain %d (zid %s)", config.node, config.domain_id, node.zid)
    camera_info: CameraIntrinsics | None = None
    last_image = 0.0
    ticker = Ticker(0.01)

    def reject(key: str, err: Exception) -> None:
        bus.rejections.add(key, f"undecodable ROS message: {type(err).__name__}: {err}")

    while True:
        if (p := poses.get_nowait()) is not None and (m := convert.humanoid_pose(
                p, config.world_frame)) is not None:
            pose_out.publish(m)
            assert p.x is not None and p.y is not None and p.yaw is not None
            tf_out.publish(convert.tf_message([convert.transform(
                p.stamp_ns, config.world_frame, config.humanoid_frame, p.x, p.y, p.yaw)]))
        if (o := odoms.get_nowait()) is not None:
            tf_out.publish(convert.tf_message([convert.transform(
                o.stamp_ns, config.world_frame, config.camera_frame, o.x, o.y, o.yaw)]))
        if (g := goals.get_nowait()) is not None:
            goal_out.publish(convert.camera_goal(g, config.world_frame))
        while (sample := odom_in.get_nowait()) is not None:
            try:
                bus.put(ODOM, convert.odometry_to_camera_pose(
                    rmw.deserialize(sample.payload.to_bytes(), convert.ODOMETRY),
                    config.T_world_odom))
            except Exception as err:
                reject(str(sample.key_expr), err)
        while goal_in is not None and (sample := goal_in.get_nowait()) is not None:
            try:
                bus.put(MISSION_GOAL, convert.pose_to_mission_goal(
                    rmw.deserialize(sample.payload.to_bytes(), convert.POSE)))
            except Exception as err:
                reject(str(sample.key_expr), err)
        if frames is not None and intrinsics is not None and image_out and info_out:
            camera_info = intrinsics.get_nowait() or camera_info
            now = time.monotonic()
            if (f := frames.get_nowait()) is not None and now - last_image >= 1 / config.image_hz \
                    and f.header.encoding is not FrameEncoding.MONO8:
                ok, jpeg = cv2.imencode(".jpg", f.image,
                                        [cv2.IMWRITE_JPEG_QUALITY, config.image_jpeg_quality])
                if ok:
                    image_out.publish(convert.compressed_image(
                        jpeg.tobytes(), f.header.stamp_ns, "camera"))
                    if camera_info is not None:
                        info_out.publish(convert.camera_info(camera_info, f.header.stamp_ns,
                                                             "camera"))
                    last_image = now
        await ticker.wait()

