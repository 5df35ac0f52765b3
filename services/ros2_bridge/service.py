"""The ``ros2_bridge`` service: Shepherd's poses, transforms and camera goals out to ROS 2 nodes
on Zenoh (rmw_zenoh), their odometry (and optionally goals) in; no ROS installation needed.

Out: ``humanoid/pose`` as PoseWithCovarianceStamped; the TF tree of ``frames`` (``/tf_static``,
transient-local: map -> odom from ``T_world_odom``, base -> camera -> optical frame from
``[geometry]``; ``/tf``: map -> humanoid; the robot's own odom -> base is the robot's to
publish); ``camera/goal`` as PoseStamped on ``goal_topic`` in ``goal_frame`` (``/goal_pose``
drives Nav2); optionally the camera image (CompressedImage) and its CameraInfo in the optical
frame, rate-limited. In: nav_msgs/Odometry on ``odom_topic`` -> ``camera/odom``; a PoseStamped
on ``mission_goal_topic`` -> ``mission/goal``, each moved into the world from its frame (one
the bridge cannot reach is refused, naming it). Every endpoint is announced with rmw_zenoh's
liveliness tokens, so ``ros2 node list``, ``ros2 topic list`` and rviz2 see it. Shepherd's
log records at WARNING and above go to /rosout (rcl_interfaces/Log; those of services in this
process); the parameter services (list, get, describe, types; read-only) answer with these
settings, so ``ros2 param list /shepherd_bridge`` works.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import cv2
from pydantic import Field, model_validator

from schemas import CameraGoal, CameraIntrinsics, CameraPose, FrameEncoding, HumanoidPose
from schemas.keys import CAMERA_GOAL, HUMANOID_POSE, INTRINSICS, MISSION_GOAL, ODOM
from services.ros2_bridge import convert, params, rmw, rosout
from services.ros2_bridge.frames import FrameNames, Tree, UnknownFrameError
from services.runtime.bus import Bus
from services.runtime.clock import Ticker
from services.runtime.config import ServiceSettings
from services.runtime.context import ServiceContext


class Settings(ServiceSettings):
    domain_id: int = Field(default=0, ge=0, le=232, description="ROS_DOMAIN_ID")
    node: str = Field(default="shepherd_bridge", pattern=r"^[A-Za-z][A-Za-z0-9_]*$",
                      description="the ROS 2 node name")
    type_hash: bool = Field(default=True, description="false for Humble (no type hashes)")
    world_frame: str = Field(default="map", description="Shepherd's world (REP-105 map)")
    odom_frame: str = Field(default="odom", description="the camera robot's odometry frame")
    base_frame: str = Field(default="base_link", description=(
        "the camera robot's base: the child of its odometry, published by the robot"))
    camera_frame: str = Field(default="camera_link", description="the camera's body frame")
    optical_frame: str = Field(default="camera_optical_frame", description=(
        "the camera's optical frame (REP-103: x right, y down, z forward); images' frame_id"))
    humanoid_frame: str = Field(default="humanoid", description="its child frame on /tf")
    goal_frame: str | None = Field(default=None, description=(
        "the frame outgoing goals are expressed in: world_frame (default) or odom_frame "
        "(Nav2 without a map)"))
    pose_topic: str | None = Field(default=None, description="default /<namespace>/humanoid/pose")
    goal_topic: str | None = Field(default=None, description=(
        "default /<namespace>/camera/goal; /goal_pose sends it to Nav2"))
    odom_topic: str = Field(default="/odom", description="nav_msgs/Odometry in: camera/odom")
    odom_tf: bool = Field(default=False, description=(
        "publish odom_frame -> base_frame from Shepherd's camera/odom: only where no ROS node "
        "publishes the robot's transform (the simulator); the bridge then takes no odometry "
        "from ROS, so it never re-publishes the robot's own"))
    T_world_odom: tuple[float, float, float] = Field(default=(0.0, 0.0, 0.0), description=(
        "the odometry frame in the world: x m, y m, yaw rad (static map -> odom)"))
    mission_goal_topic: str | None = Field(default=None, description=(
        "a PoseStamped here becomes mission/goal (e.g. /shepherd/mission/goal)"))
    image: bool = Field(default=False, description="also publish the camera's image + info")
    image_hz: float = Field(default=5.0, gt=0.0, le=60.0, description="image rate out")
    image_jpeg_quality: int = Field(default=80, ge=10, le=100, description="of the image")

    def frame_names(self) -> FrameNames:
        return FrameNames(world=self.world_frame, odom=self.odom_frame, base=self.base_frame,
                          camera=self.camera_frame, optical=self.optical_frame,
                          humanoid=self.humanoid_frame)

    @model_validator(mode="after")
    def _one_tree(self) -> Settings:
        self.frame_names().check()
        if self.goal_frame not in (None, self.world_frame, self.odom_frame):
            raise ValueError(f"goal_frame {self.goal_frame!r} must be world_frame "
                             f"({self.world_frame!r}) or odom_frame ({self.odom_frame!r})")
        return self


@dataclass
class RosPublisher:
    """One ROS 2 topic we publish: its Zenoh publisher, GID (rmw_zenoh's, from its token) and
    sequence numbers."""

    publisher: Any
    ros_type: str
    gid: bytes
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
                  qos: rmw.Qos) -> tuple[str, str]:
        """(data key, token) of a new endpoint, its token declared."""
        self.entities += 1
        c = self.config
        token = rmw.entity_token(c.domain_id, self.zid, 0, self.entities, kind, c.node, topic,
                                 ros_type, qos, with_hash=c.type_hash)
        self.bus.declare_token(token)
        return rmw.data_key(c.domain_id, topic, ros_type, c.type_hash), token

    def publisher(self, topic: str, ros_type: str, depth: int = 10,
                  transient_local: bool = False, lifespan_s: int = 0) -> RosPublisher:
        """A publisher; ``transient_local`` keeps the last ``depth`` samples for late joiners
        as rmw_zenoh does (a zenoh-ext advanced publisher with a cache, detectable)."""
        qos = rmw.Qos(durability="transient_local" if transient_local else "volatile",
                      depth=depth, lifespan_s=lifespan_s)
        key, token = self._announce("MP", topic, ros_type, qos)
        publisher = self.bus.raw_publisher(key, cache=depth if transient_local else 0)
        return RosPublisher(publisher, ros_type, rmw.entity_gid(token))

    def service(self, name: str, srv_type: str, hash_: str,
                answer: Callable[[Any], Any]) -> None:
        """A service server as rmw_zenoh's: a complete queryable on the service's key (any
        type hash: Humble clients too); each request's CDR answered with ``answer``'s, the
        reply carrying the request's sequence number and client GID."""
        self.entities += 1
        c = self.config
        self.bus.declare_token(rmw.entity_token(
            c.domain_id, self.zid, 0, self.entities, "SS", c.node, name, srv_type,
            rmw.Qos(depth=10), with_hash=c.type_hash, hash_=hash_))
        key = rmw.data_key(c.domain_id, name, srv_type, c.type_hash, hash_)
        rejections = self.bus.rejections

        def on_query(query: Any) -> None:
            try:
                if query.attachment is None or query.payload is None:
                    raise ValueError("a service request needs its payload and attachment")
                sequence, _, client_gid = rmw.unpack_attachment(query.attachment.to_bytes())
                response = answer(rmw.deserialize(query.payload.to_bytes(),
                                                  f"{srv_type}_Request"))
                query.reply(query.key_expr, rmw.serialize(response, f"{srv_type}_Response"),
                            attachment=rmw.pack_attachment(sequence, time.time_ns(),
                                                           client_gid))
            except Exception as err:
                rejections.add(key, f"bad service request: {type(err).__name__}: {err}")

        self.bus.raw_queryable(key.rsplit("/", 1)[0] + "/*", on_query)

    def subscription(self, topic: str, ros_type: str, depth: int = 10) -> Any:
        """Samples of ``topic`` from any publisher of its type (any hash: Humble's too)."""
        key, _ = self._announce("MS", topic, ros_type, rmw.Qos(depth=depth))
        return self.bus.subscribe_raw(key.rsplit("/", 1)[0] + "/*", queue=depth)


async def main(ctx: ServiceContext, config: Settings) -> None:
    bus, log = ctx.bus, ctx.log
    ns = ctx.deployment.namespace
    tree = Tree(config.frame_names(), config.T_world_odom, ctx.geometry)
    names = tree.names
    goal_frame = config.goal_frame or names.world
    node = RosNode(bus, config, str(bus.session.info.zid()))
    pose_out = node.publisher(config.pose_topic or f"/{ns}/humanoid/pose", convert.POSE_COV)
    tf_out = node.publisher("/tf", convert.TF, depth=100)
    tf_static_out = node.publisher("/tf_static", convert.TF, depth=1, transient_local=True)
    goal_out = node.publisher(config.goal_topic or f"/{ns}/camera/goal", convert.POSE)
    odom_in = (None if config.odom_tf else
               node.subscription(config.odom_topic, convert.ODOMETRY))
    odoms = bus.subscribe(ODOM, CameraPose, latest=True) if config.odom_tf else None
    goal_in = (node.subscription(config.mission_goal_topic, convert.POSE)
               if config.mission_goal_topic else None)
    poses = bus.subscribe(HUMANOID_POSE, HumanoidPose, latest=True)
    goals = bus.subscribe(CAMERA_GOAL, CameraGoal, latest=True)
    image_out = info_out = None
    frames = None
    camera_info: list[CameraIntrinsics] = []  # the latest, once known
    tasks: list[asyncio.Task[None]] = []
    if config.image:
        image_out = node.publisher(f"/{ns}/camera/image/compressed", convert.IMAGE, depth=1)
        info_out = node.publisher(f"/{ns}/camera/camera_info", convert.CAMERA_INFO, depth=1)
        frames = bus.subscribe_frames()
        tasks.append(asyncio.create_task(_follow_intrinsics(bus, camera_info)))
    rosout_out = node.publisher("/rosout", convert.LOG, depth=rosout.DEPTH,
                                transient_local=True, lifespan_s=10)
    rosout_handler = rosout.RosoutHandler()
    logging.getLogger("shepherd").addHandler(rosout_handler)
    _serve_parameters(node, config)
    static_ns = time.time_ns()
    tf_static_out.publish(convert.tf_message([
        convert.transform_T(static_ns, parent, child, T)
        for parent, child, T in tree.static_transforms()]))
    log.info("ROS 2 node %s on domain %d (zid %s); goals in %s", config.node, config.domain_id,
             node.zid, goal_frame)
    last_image = 0.0
    ticker = Ticker(0.01)

    def reject(key: str, reason: str) -> None:
        bus.rejections.add(key, reason)

    try:
        while True:
            if (p := poses.get_nowait()) is not None and (m := convert.humanoid_pose(
                    p, names.world)) is not None:
                pose_out.publish(m)
                assert p.x is not None and p.y is not None and p.yaw is not None
                tf_out.publish(convert.tf_message([convert.transform(
                    p.stamp_ns, names.world, names.humanoid, p.x, p.y, p.yaw)]))
            for record in rosout_handler.drain():
                rosout_out.publish(convert.log_message(record))
            if (g := goals.get_nowait()) is not None:
                goal_out.publish(convert.camera_goal(g, tree, goal_frame))
            if odoms is not None and (o := odoms.get_nowait()) is not None:
                x, y, yaw = tree.from_world(names.odom, (o.x, o.y, o.yaw))
                tf_out.publish(convert.tf_message([convert.transform(
                    o.stamp_ns, names.odom, names.base, x, y, yaw)]))
            while odom_in is not None and (sample := odom_in.get_nowait()) is not None:
                _take(sample, convert.ODOMETRY, lambda m: bus.put(
                    ODOM, convert.odometry_to_camera_pose(m, tree)), reject)
            while goal_in is not None and (sample := goal_in.get_nowait()) is not None:
                _take(sample, convert.POSE, lambda m: bus.put(
                    MISSION_GOAL, convert.pose_to_mission_goal(m, tree)), reject)
            if frames is not None and image_out and info_out:
                now = time.monotonic()
                if (f := frames.get_nowait()) is not None and \
                        now - last_image >= 1 / config.image_hz \
                        and f.header.encoding is not FrameEncoding.MONO8:
                    ok, jpeg = cv2.imencode(".jpg", f.image, [cv2.IMWRITE_JPEG_QUALITY,
                                                              config.image_jpeg_quality])
                    if ok:
                        image_out.publish(convert.compressed_image(
                            jpeg.tobytes(), f.header.stamp_ns, names.optical))
                        if camera_info:
                            info_out.publish(convert.camera_info(
                                camera_info[-1], f.header.stamp_ns, names.optical))
                        last_image = now
            await ticker.wait()
    finally:
        logging.getLogger("shepherd").removeHandler(rosout_handler)
        for task in tasks:
            task.cancel()


def _serve_parameters(node: RosNode, config: Settings) -> None:
    """ROS 2's read parameter services of ``/<node>``, answered with ``config``."""
    parameters = params.Parameters(
        config.model_dump(), {n: f.description or "" for n, f in Settings.model_fields.items()})
    for service, (srv_type, request, response) in params.PARAMETER_SERVICES.items():
        node.service(f"/{config.node}/{service}", srv_type,
                     params.service_type_hash(srv_type, request, response),
                     parameters.handler(service))


def _take(sample: Any, ros_type: str, use: Callable[[Any], None],
          reject: Callable[[str, str], None]) -> None:
    """Decode a ROS sample and ``use`` it; an undecodable one or one in a frame the bridge
    cannot reach is refused (logged, counted) with the reason."""
    key = str(sample.key_expr)
    try:
        message = rmw.deserialize(sample.payload.to_bytes(), ros_type)
    except Exception as err:
        reject(key, f"undecodable ROS message: {type(err).__name__}: {err}")
        return
    try:
        use(message)
    except UnknownFrameError as err:
        reject(key, str(err))


async def _follow_intrinsics(bus: Bus, latest: list[CameraIntrinsics]) -> None:
    """Keep ``latest`` holding the camera's intrinsics: asked of the ``camera/intrinsics``
    queryable (put once, before the bridge may have started) until one answers, then
    followed as they are put."""
    updates = bus.subscribe(INTRINSICS, CameraIntrinsics, latest=True)
    while not latest:
        latest.extend(await bus.get(INTRINSICS, CameraIntrinsics, timeout=1.0))
        if not latest and (put := updates.get_nowait()) is not None:
            latest.append(put)
        if not latest:
            await asyncio.sleep(0.5)
    while True:
        latest.append(await updates.recv())
        del latest[:-1]
