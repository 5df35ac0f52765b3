"""The ROS 2 bridge seen by an independent peer: ``zenoh-ros2-sdk`` (PyPI, pinned in the dev
extra), which builds rmw_zenoh's keys, tokens and RIHS01 hashes itself from ``.msg`` files.
Offline, it is handed rosbags' definitions (tests/helpers/ros_peer.py), and its hashes are
checked against rosbags' before its verdicts are trusted.

Where the peer deviates from rmw_zenoh, the tests say so: it writes the depth of a keep-last-42
profile (rmw_zenoh's default, which rmw_zenoh leaves empty), gives its endpoints random GIDs
(rmw_zenoh hashes the token), and hashes bounded sequences (``T[<=N]``) differently from ROS 2,
so its hash of rcl_interfaces/ParameterDescriptor, and of DescribeParameters, is wrong.
"""

from __future__ import annotations

import asyncio
import functools
import math
import threading
import time
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from schemas import CameraGoal, CameraPose, HumanoidPose, MarkerInCamera, MissionGoal
from schemas.keys import CAMERA_GOAL, HUMANOID_POSE, MISSION_GOAL, ODOM, STATS
from schemas.messages import ServiceStats
from services.core.geometry import T_floor, floor_pose
from services.core.mounts import Geometry
from services.ros2_bridge import convert, params, rmw
from services.runtime.config import parse_deployment
from services.runtime.launcher import run_deployment
from tests.conftest import wait_alive_async, wait_matched_key
from tests.helpers import ros_peer

TOPIC_TYPES = [convert.POSE_COV, convert.POSE, convert.TF, convert.ODOMETRY, convert.IMAGE,
               convert.CAMERA_INFO, convert.LOG]
PARAM_TYPES = ["rcl_interfaces/msg/ListParametersResult", "rcl_interfaces/msg/ParameterValue",
               "rcl_interfaces/msg/ParameterDescriptor"]
T_WORLD_ODOM = (1.0, 2.0, math.pi / 2)
GEOMETRY = {"camera_height_m": 0.25, "camera_forward_m": 0.05, "camera_pitch_rad": 0.1}
STAMP = 1_700_000_000_123_456_789


@pytest.fixture
def peer(router: str, tmp_path: Path) -> Iterator[Any]:
    session = ros_peer.open_peer(tmp_path / "defs", router, TOPIC_TYPES + PARAM_TYPES)
    yield session
    ros_peer.close_peer()


def _sdk_hash(ros_type: str) -> str:
    from zenoh_ros2_sdk import get_registry
    from zenoh_ros2_sdk.utils import get_type_hash, load_dependencies_recursive
    registry = get_registry()
    definition = registry.get_msg_file_path(ros_type).read_text()
    return str(get_type_hash(ros_type, msg_definition=definition,
                             dependencies=load_dependencies_recursive(ros_type, definition,
                                                                      registry)))


def test_the_peer_hashes_as_rosbags_does_before_it_is_trusted(peer):
    from zenoh_ros2_sdk.qos import QosProfile
    from zenoh_ros2_sdk.utils import compute_service_type_hash
    for ros_type in TOPIC_TYPES + PARAM_TYPES[:2]:
        assert _sdk_hash(ros_type) == rmw.type_hash(ros_type), ros_type
    # the peer's deviation: a bounded sequence (ParameterDescriptor's ranges, T[<=1]) hashed
    # unlike ROS 2 (rosbags' hash is the one Jazzy ships in ParameterDescriptor.json)
    assert rmw.type_hash("rcl_interfaces/msg/ParameterDescriptor") == (
        "RIHS01_52175dbfda6c51153101d33d2a9da05743f66f02d5ab2ca9ec4709b46b73d704")
    assert _sdk_hash("rcl_interfaces/msg/ParameterDescriptor") != rmw.type_hash(
        "rcl_interfaces/msg/ParameterDescriptor")
    # services: the peer and the bridge agree with rmw_zenoh's documented AddTwoInts key ...
    add_two_ints = "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
    assert params.service_type_hash("example_interfaces/srv/AddTwoInts", "int64 a\nint64 b",
                                    "int64 sum") == add_two_ints
    assert compute_service_type_hash("example_interfaces/srv/AddTwoInts", "int64 a\nint64 b",
                                     "int64 sum") == add_two_ints
    # ... and on the parameter services whose types the peer hashes right
    for name in ("list_parameters", "get_parameters", "get_parameter_types"):
        srv_type, request, response = params.PARAMETER_SERVICES[name]
        request_def, _, response_def = ros_peer.SRV_DEFINITIONS[srv_type.rsplit("/", 1)[1]
                                                                ].partition("---\n")
        assert compute_service_type_hash(srv_type, request_def, response_def, _deps(
            srv_type, request_def, response_def)) == params.service_type_hash(
            srv_type, request, response), srv_type
    # the peer's other deviation: it writes the depth of a keep-last-42 profile, rmw_zenoh's
    # default, which rmw_zenoh (and the bridge) leave empty
    assert QosProfile(history_depth=42).encode() == "::,42:,:,:,,"
    assert rmw.Qos(depth=42).key() == "::,:,:,:,,"


def _deps(srv_type: str, request: str, response: str) -> dict[str, str]:
    from zenoh_ros2_sdk import get_registry
    from zenoh_ros2_sdk.utils import load_dependencies_recursive
    registry = get_registry()
    return {**load_dependencies_recursive(f"{srv_type}_Request", request, registry),
            **load_dependencies_recursive(f"{srv_type}_Response", response, registry)}


def _pose(x: float, y: float, yaw: float) -> HumanoidPose:
    return HumanoidPose(seq=1, stamp_ns=STAMP, x=x, y=y, yaw=yaw,
                        covariance=((1e-4, 0, 0), (0, 2e-4, 0), (0, 0, 3e-3)),
                        marker_in_camera=MarkerInCamera(position=(0, 0, 0.3),
                                                        quaternion=(0, 0, 0, 1)),
                        reprojection_px=0.1)


class Received:
    """What the peer's subscriptions got, by topic (callbacks run on Zenoh's threads)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.by_topic: dict[str, list[Any]] = defaultdict(list)

    def on(self, topic: str) -> Any:
        def callback(message: Any) -> None:
            with self.lock:
                self.by_topic[topic].append(message)
        return callback

    def get(self, topic: str) -> list[Any]:
        with self.lock:
            return list(self.by_topic[topic])


async def _until(check: Any, what: str, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not check():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        await asyncio.sleep(0.05)


def _edges(samples: list[tuple[bytes, bytes]], store: Any
           ) -> dict[tuple[str, str], tuple[set[bytes], Any]]:
    """(parent, child) -> (GIDs of the publishers that sent it, the latest transform)."""
    out: dict[tuple[str, str], tuple[set[bytes], Any]] = {}
    for payload, attachment in samples:
        gid = rmw.unpack_attachment(attachment)[2]
        for t in store.deserialize_cdr(payload, convert.TF).transforms:
            gids, _ = out.get((t.header.frame_id, t.child_frame_id), (set(), None))
            out[(t.header.frame_id, t.child_frame_id)] = (gids | {gid}, t)
    return out


def _T(t: Any) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    q, p = t.transform.rotation, t.transform.translation
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = (p.x, p.y, p.z)
    return T


@pytest.mark.slow
def test_the_peer_sees_one_tf_tree_and_shepherds_values(router, make_bus, peer):
    from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber, get_topic_info
    from zenoh_ros2_sdk.qos import QosDurability, QosProfile
    dep = parse_deployment({
        "zenoh": {"connect": [router], "multicast_scouting": False}, "geometry": GEOMETRY,
        "services": {"ros2_bridge": {"goal_topic": "/goal_pose", "goal_frame": "odom",
                                     "T_world_odom": list(T_WORLD_ODOM),
                                     "mission_goal_topic": "/shepherd/mission/goal"}}})
    host, port = router.removeprefix("tcp/").rsplit(":", 1)
    where = {"router_ip": host, "router_port": int(port)}
    bus = make_bus("shepherd")
    got = Received()
    tf_samples: list[tuple[bytes, bytes]] = []  # /tf and /tf_static with their attachments
    lock = threading.Lock()

    def on_tf(sample: Any) -> None:
        with lock:
            tf_samples.append((sample.payload.to_bytes(), sample.attachment.to_bytes()))

    raw = [peer.session.declare_subscriber(rmw.data_key(0, topic, convert.TF), on_tf)
           for topic in ("/tf", "/tf_static")]
    endpoints: list[Any] = []
    goal = CameraGoal(stamp_ns=STAMP, x=0.3, y=0.1, yaw=-1.0, reason="d")

    async def go() -> tuple[Any, list[CameraPose], list[MissionGoal], ServiceStats]:
        odoms = bus.subscribe(ODOM, CameraPose, latest=False, queue=4)
        missions = bus.subscribe(MISSION_GOAL, MissionGoal, latest=False, queue=4)
        task = asyncio.create_task(run_deployment(dep, duration=30))
        await wait_alive_async(bus.session, "ros2_bridge")
        info = await asyncio.to_thread(get_topic_info, "/tf_static", timeout=2.0, verbose=True,
                                       **where)
        # subscriptions made after the bridge started: /tf_static must come from its cache
        for topic, ros_type, qos in (
                ("/tf_static", convert.TF, QosProfile(durability=QosDurability.TRANSIENT_LOCAL,
                                                       history_depth=1)),
                ("/tf", convert.TF, None), ("/shepherd/humanoid/pose", convert.POSE_COV, None),
                ("/goal_pose", convert.POSE, None)):
            endpoints.append(await asyncio.to_thread(
                ROS2Subscriber, topic, ros_type, got.on(topic), qos=qos, **where))
        robot_odom = ROS2Publisher("/odom", convert.ODOMETRY, node_name="robot", **where)
        robot_tf = ROS2Publisher("/tf", convert.TF, node_name="robot", **where)
        mission = ROS2Publisher("/shepherd/mission/goal", convert.POSE, node_name="rviz", **where)
        endpoints.extend([robot_odom, robot_tf, mission])
        await _until(lambda: got.get("/tf_static"), "/tf_static from the cache")
        for topic, ros_type in (("/odom", convert.ODOMETRY),
                                ("/shepherd/mission/goal", convert.POSE)):
            # the bridge's subscriptions have reached the peer's side of the router
            await wait_matched_key(peer.session, rmw.data_key(0, topic, ros_type),
                                   remote_only=True)

        T = rmw.typestore().types
        odom_pose = T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](
                x=0.5, y=0.0, z=0.0), orientation=convert.yaw_quaternion(0.3)),
            covariance=np.zeros(36))
        zero = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        robot_odom.publish(header=convert.header(STAMP, "odom"), child_frame_id="base_link",
                           pose=odom_pose, twist=T["geometry_msgs/msg/TwistWithCovariance"](
                               twist=T["geometry_msgs/msg/Twist"](linear=zero, angular=zero),
                               covariance=np.zeros(36)))
        robot_tf.publish(transforms=[convert.transform(STAMP, "odom", "base_link", 0.5, 0.0,
                                                       0.3)])
        for frame in ("map", "base_footprint"):
            mission.publish(header=convert.header(STAMP, frame), pose=T[
                "geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](
                    x=0.9, y=-0.1, z=0.0), orientation=convert.yaw_quaternion(0.0)))
        bus.put(HUMANOID_POSE, _pose(0.6, -0.2, 0.5))
        bus.put(CAMERA_GOAL, goal)
        await _until(lambda: got.get("/shepherd/humanoid/pose") and got.get("/goal_pose")
                     and len(got.get("/tf")) >= 2, "pose, goal and /tf at the peer")
        camera = [await odoms.recv(timeout=30)]
        in_map = [await missions.recv(timeout=30)]
        stats: list[ServiceStats] = []

        def refused() -> bool:
            return bool(stats and stats[0].rejected)

        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:  # the refused goal shows in the bridge's stats
            stats = await bus.get(f"{STATS}/ros2_bridge", ServiceStats)
            if refused():
                break
            await asyncio.sleep(0.1)
        await asyncio.sleep(0.2)
        task.cancel()
        return info, camera, in_map, stats[0]

    try:
        info, camera, in_map, stats = asyncio.run(go())
    finally:
        for e in endpoints:
            e.close()
        for s in raw:
            s.undeclare()

    # discovery: the peer finds the bridge's /tf_static publisher, transient-local, depth 1
    bridge = [p for p in info.publishers if p.node_name == "shepherd_bridge"]
    assert len(bridge) == 1 and bridge[0].topic_type == convert.TF
    qos = QosProfile.decode(bridge[0].qos)
    assert qos.durability == QosDurability.TRANSIENT_LOCAL and qos.history_depth == 1

    # one tree: every child one parent, every transform one publisher, from map to all
    with lock:
        edges = _edges(tf_samples, peer.store)
    for msg in got.get("/tf_static") + got.get("/tf"):  # the SDK's own decoding agrees
        for t in msg.transforms:
            assert (t.header.frame_id, t.child_frame_id) in edges
    parents: dict[str, set[str]] = defaultdict(set)
    publishers: dict[str, set[bytes]] = defaultdict(set)
    for (parent, child), (gids, _) in edges.items():
        parents[child].add(parent)
        publishers[child] |= gids
    assert all(len(p) == 1 for p in parents.values()), parents
    assert all(len(g) == 1 for g in publishers.values()), publishers
    reached, todo = {"map"}, ["map"]
    while todo:
        frame = todo.pop()
        for (parent, child) in edges:
            if parent == frame and child not in reached:
                reached.add(child)
                todo.append(child)
    assert {"odom", "base_link", "camera_link", "camera_optical_frame",
            "humanoid"} <= reached == set(parents) | {"map"}

    # the values are Shepherd's
    T_map_odom = _T(edges[("map", "odom")][1])
    assert np.allclose(T_map_odom, T_floor(*T_WORLD_ODOM))
    T_base_optical = _T(edges[("base_link", "camera_link")][1]) @ _T(
        edges[("camera_link", "camera_optical_frame")][1])
    assert np.allclose(T_base_optical, Geometry(**GEOMETRY).T_base_camera())
    humanoid = edges[("map", "humanoid")][1].transform.translation
    assert (humanoid.x, humanoid.y) == pytest.approx((0.6, -0.2))
    pose = got.get("/shepherd/humanoid/pose")[-1]
    assert pose.header.frame_id == "map"
    assert (pose.pose.pose.position.x, pose.pose.pose.position.y) == pytest.approx((0.6, -0.2))
    assert np.array(pose.pose.covariance).reshape(6, 6)[1, 1] == pytest.approx(2e-4)

    # the goal reaches /goal_pose in odom, the frame Nav2 was told; map -> odom takes it back
    # onto the camera goal Shepherd computed
    nav_goal = got.get("/goal_pose")[-1]
    assert nav_goal.header.frame_id == "odom"
    p = nav_goal.pose.position
    in_odom = (p.x, p.y, convert.quaternion_yaw(nav_goal.pose.orientation))
    assert (p.x, p.y) != pytest.approx((goal.x, goal.y))
    assert floor_pose(T_map_odom @ T_floor(*in_odom)) == pytest.approx((goal.x, goal.y, goal.yaw))

    # the robot's odometry arrives in the world; a goal in map as it stands; one in a frame
    # the bridge cannot reach is refused with the frame's name
    assert (camera[0].x, camera[0].y) == pytest.approx((1.0, 2.5))
    assert camera[0].yaw == pytest.approx(0.3 + math.pi / 2)
    assert in_map[0].waypoints == [pytest.approx((0.9, -0.1))]
    reasons = stats.rejected[rmw.data_key(0, "/shepherd/mission/goal", convert.POSE)]
    assert len(reasons) == 1 and "frame 'base_footprint'" in next(iter(reasons))


@pytest.mark.slow
def test_the_peer_reads_rosout_and_the_parameters(router, make_bus, peer):
    from zenoh_ros2_sdk import ROS2Publisher, ROS2ServiceClient, ROS2Subscriber
    from zenoh_ros2_sdk.qos import QosDurability, QosProfile
    dep = parse_deployment({
        "zenoh": {"connect": [router], "multicast_scouting": False},
        "services": {"ros2_bridge": {"goal_frame": "odom", "T_world_odom": list(T_WORLD_ODOM),
                                     "mission_goal_topic": "/shepherd/mission/goal"}}})
    host, port = router.removeprefix("tcp/").rsplit(":", 1)
    where = {"router_ip": host, "router_port": int(port)}
    bus = make_bus("shepherd")
    got = Received()
    rosout_gids: list[bytes] = []
    raw = peer.session.declare_subscriber(
        rmw.data_key(0, "/rosout", convert.LOG),
        lambda s: rosout_gids.append(rmw.unpack_attachment(s.attachment.to_bytes())[2]))
    endpoints: list[Any] = []
    answers: dict[str, Any] = {}

    async def go() -> list[str]:
        task = asyncio.create_task(run_deployment(dep, duration=30))
        await wait_alive_async(bus.session, "ros2_bridge")
        mission = ROS2Publisher("/shepherd/mission/goal", convert.POSE, node_name="rviz", **where)
        endpoints.append(mission)
        await wait_matched_key(peer.session, rmw.data_key(0, "/shepherd/mission/goal",
                                                          convert.POSE), remote_only=True)
        T = rmw.typestore().types
        mission.publish(header=convert.header(STAMP, "base_footprint"), pose=T[
            "geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](
                x=0.9, y=-0.1, z=0.0), orientation=convert.yaw_quaternion(0.0)))
        await _until(lambda: rosout_gids, "the warning on /rosout")
        # a late rqt_console still gets it: /rosout is transient-local, as rcl's
        endpoints.append(await asyncio.to_thread(
            ROS2Subscriber, "/rosout", convert.LOG, got.on("/rosout"),
            qos=QosProfile(durability=QosDurability.TRANSIENT_LOCAL, history_depth=1000),
            **where))
        await _until(lambda: got.get("/rosout"), "/rosout from the cache")
        for name, kwargs in (("list_parameters", {"prefixes": [], "depth": 0}),
                             ("get_parameters", {"names": ["goal_frame", "T_world_odom",
                                                           "image_hz", "pose_topic"]}),
                             ("get_parameter_types", {"names": ["goal_frame", "image"]})):
            srv_type = params.PARAMETER_SERVICES[name][0]
            client = await asyncio.to_thread(
                ROS2ServiceClient, f"/shepherd_bridge/{name}", srv_type, timeout=5.0, **where)
            endpoints.append(client)
            answers[name] = await asyncio.to_thread(functools.partial(client.call, **kwargs))
        # DescribeParameters: the peer's hash of it is wrong (see the module's docstring), so
        # it is given the right one, as a ROS 2 client has it
        describe, request, response = params.PARAMETER_SERVICES["describe_parameters"]
        client = await asyncio.to_thread(
            ROS2ServiceClient, "/shepherd_bridge/describe_parameters", describe, timeout=5.0,
            type_hash=params.service_type_hash(describe, request, response), **where)
        endpoints.append(client)
        answers["describe_parameters"] = await asyncio.to_thread(
            functools.partial(client.call, names=["goal_frame"]))
        tokens = [str(r.ok.key_expr) for r in await asyncio.to_thread(
            lambda: list(peer.liveliness.get("@ros2_lv/0/**", timeout=1.0))) if r.ok]
        task.cancel()
        return tokens

    try:
        tokens = asyncio.run(go())
    finally:
        for e in endpoints:
            e.close()
        raw.undeclare()

    log = got.get("/rosout")[0]
    assert log.level == 30 and log.name == "shepherd.ros2_bridge"
    assert "frame 'base_footprint'" in log.msg
    # the GID in the attachment is the one rmw_zenoh derives from the publisher's token
    rosout_token = next(t for t in tokens if "/MP/" in t and "/%rosout/" in t)
    assert rosout_token.endswith("/:1:,1000:,:10,:,,")  # rcl's rosout QoS: lifespan 10 s
    assert set(rosout_gids) == {rmw.entity_gid(rosout_token)}
    assert sum("/SS/%/%/shepherd_bridge/%shepherd_bridge%" in t for t in tokens) == 4

    names = list(answers["list_parameters"].result.names)
    assert {"goal_frame", "T_world_odom", "world_frame", "odom_topic"} <= set(names)
    goal_frame, t_world_odom, image_hz, pose_topic = answers["get_parameters"].values
    assert (goal_frame.type, goal_frame.string_value) == (params.STRING, "odom")
    assert t_world_odom.type == params.DOUBLE_ARRAY
    assert list(t_world_odom.double_array_value) == pytest.approx(T_WORLD_ODOM)
    assert (image_hz.type, image_hz.double_value) == (params.DOUBLE, 5.0)
    assert pose_topic.type == params.NOT_SET
    assert list(answers["get_parameter_types"].types) == [params.STRING, params.BOOL]
    descriptor, = answers["describe_parameters"].descriptors
    assert descriptor.read_only and descriptor.name == "goal_frame"
    assert "frame outgoing goals" in descriptor.description


@pytest.mark.slow
def test_humble_mode_serves_the_peer_without_type_hashes(router, make_bus, peer):
    from zenoh_ros2_sdk import ROS2ServiceClient, ROS2Subscriber
    from zenoh_ros2_sdk.qos import QosDurability, QosProfile
    dep = parse_deployment({"zenoh": {"connect": [router], "multicast_scouting": False},
                            "services": {"ros2_bridge": {"type_hash": False}}})
    host, port = router.removeprefix("tcp/").rsplit(":", 1)
    where = {"router_ip": host, "router_port": int(port), "type_hash": rmw.NO_HASH}
    bus = make_bus("shepherd")
    got = Received()
    endpoints: list[Any] = []

    async def go() -> Any:
        task = asyncio.create_task(run_deployment(dep, duration=30))
        await wait_alive_async(bus.session, "ros2_bridge")
        endpoints.append(await asyncio.to_thread(
            ROS2Subscriber, "/tf_static", convert.TF, got.on("/tf_static"),
            qos=QosProfile(durability=QosDurability.TRANSIENT_LOCAL, history_depth=1), **where))
        await _until(lambda: got.get("/tf_static"), "/tf_static (Humble) from the cache")
        client = await asyncio.to_thread(
            ROS2ServiceClient, "/shepherd_bridge/list_parameters",
            params.PARAMETER_SERVICES["list_parameters"][0], timeout=5.0, **where)
        endpoints.append(client)
        answer = await asyncio.to_thread(functools.partial(client.call, prefixes=[], depth=0))
        task.cancel()
        return answer

    try:
        answer = asyncio.run(go())
    finally:
        for e in endpoints:
            e.close()
    assert len(got.get("/tf_static")[0].transforms) == 3
    assert "type_hash" in answer.result.names
