"""The ROS 2 bridge against rmw_zenoh's documented wire format, with rosbags (an independent
CDR implementation and hash computer) on the other side."""

from __future__ import annotations

import asyncio
import math
import struct
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import zenoh
from scipy.spatial.transform import Rotation

from schemas import (
    CameraGoal,
    CameraPose,
    HumanoidPose,
    MarkerInCamera,
    MissionGoal,
    ServiceStats,
)
from schemas.keys import CAMERA_GOAL, HUMANOID_POSE, MISSION_GOAL, ODOM, STATS
from services.ros2_bridge import convert, rmw
from services.ros2_bridge.frames import FrameNames, Tree, UnknownFrameError
from services.runtime.config import parse_deployment
from services.runtime.launcher import run_deployment
from tests.conftest import wait_alive_async, wait_for, wait_matched, wait_matched_key

CHATTER_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


def test_data_keys_match_rmw_zenohs_design_document():
    assert rmw.data_key(0, "/chatter", "std_msgs/msg/String") == (
        f"0/chatter/std_msgs::msg::dds_::String_/{CHATTER_HASH}")
    assert rmw.data_key(0, "/chatter", "std_msgs/msg/String", with_hash=False) == (
        "0/chatter/std_msgs::msg::dds_::String_/TypeHashNotSupported")  # Humble
    assert rmw.data_key(3, "/shepherd/humanoid/pose", convert.POSE_COV).startswith(
        "3/shepherd/humanoid/pose/geometry_msgs::msg::dds_::PoseWithCovarianceStamped_/RIHS01_")
    with pytest.raises(ValueError, match="must be absolute"):
        rmw.data_key(0, "chatter", "std_msgs/msg/String")


@pytest.mark.parametrize("ros_type", [convert.POSE_COV, convert.POSE, convert.TF,
                                      convert.ODOMETRY, convert.IMAGE, convert.CAMERA_INFO])
def test_type_hashes_are_rosbags_rihs01(ros_type: str):
    from rosbags.typesys import Stores, get_typestore
    expected = get_typestore(Stores.ROS2_JAZZY).hash_rihs01(ros_type)
    assert rmw.data_key(0, "/t", ros_type).endswith("/" + expected)
    assert len(expected) == len("RIHS01_") + 64


def test_liveliness_tokens_match_rmw_zenohs_design_document():
    assert rmw.node_token(0, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "listener") == (
        "@ros2_lv/0/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener")
    assert rmw.entity_token(
        0, "8b20917502ee955ac4476e0266340d5c", 0, 10, "MP", "talker", "/chatter",
        "std_msgs/msg/String", rmw.Qos(depth=7)) == (
        "@ros2_lv/0/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
        f"std_msgs::msg::dds_::String_/{CHATTER_HASH}/::,7:,:,:,,")
    assert rmw.entity_token(
        2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, 10, "MS", "listener", "/chatter",
        "std_msgs/msg/String", rmw.Qos(depth=10)) == (
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
        f"std_msgs::msg::dds_::String_/{CHATTER_HASH}/::,10:,:,:,,")
    # names with slashes, a namespace, non-default QoS
    token = rmw.entity_token(0, "ab", 2, 12, "MP", "imu_node", "/veh/imu/data",
                             "std_msgs/msg/String", rmw.Qos("best_effort", depth=5),
                             namespace="/veh")
    assert "/NN/" not in token and "/MP/%/%veh/imu_node/%veh%imu%data/" in token
    assert token.endswith("/2::,5:,:,:,,")
    assert rmw.Qos(durability="transient_local", depth=1).key() == ":1:,1:,:,:,,"


def test_the_attachment_is_rmw_zenohs_33_bytes():
    gid = bytes(range(16))
    data = rmw.pack_attachment(7, 1_700_000_000_123_456_789, gid)
    assert len(data) == 33 and data[16] == 0x10 and data[17:] == gid
    assert struct.unpack("<qq", data[:16]) == (7, 1_700_000_000_123_456_789)
    assert rmw.unpack_attachment(data) == (7, 1_700_000_000_123_456_789, gid)
    with pytest.raises(ValueError, match="33 bytes"):
        rmw.unpack_attachment(data[:-1])
    with pytest.raises(ValueError, match="16 bytes"):
        rmw.pack_attachment(1, 1, b"short")


def test_the_publisher_gid_is_rmw_zenohs_hash_of_the_token():
    # the vector from rmw_zenoh_cpp's own simplified_xxhash3.cpp (compiled, fed this token,
    # low64 then high64 little-endian as liveliness::Entity copies them)
    token = rmw.entity_token(0, "8b20917502ee955ac4476e0266340d5c", 0, 10, "MP", "talker",
                             "/chatter", "std_msgs/msg/String", rmw.Qos(depth=7))
    assert rmw.entity_gid(token).hex() == "eb85fa883b7846dc448a4501890ad062"
    assert rmw.entity_gid("abc").hex() == "50392f89945faf7885613a73b65ab006"


def test_the_static_tree_places_the_camera_as_the_geometry_does():
    from services.core.mounts import Geometry
    g = Geometry(camera_height_m=0.31, camera_forward_m=0.07, camera_pitch_rad=0.2)
    tree = Tree(FrameNames(), (1.0, 2.0, math.pi / 2), g)
    (w, o, T_map_odom), (b, c, T_base_link_camera), (c2, opt, T_camera_optical) = (
        tree.static_transforms())
    assert (w, o, b, c, c2, opt) == ("map", "odom", "base_link", "camera_link", "camera_link",
                                     "camera_optical_frame")
    assert np.allclose(T_base_link_camera @ T_camera_optical, g.T_base_camera())
    assert np.allclose(T_map_odom[:3, 3], (1.0, 2.0, 0.0))
    # through the wire and back: the quaternion of each transform is the rotation's
    for parent, child, T in tree.static_transforms():
        msg = rmw.deserialize(rmw.serialize(convert.tf_message([convert.transform_T(
            5, parent, child, T)]), convert.TF), convert.TF).transforms[0]
        q = msg.transform.rotation
        assert np.allclose(Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix(), T[:3, :3])
        assert (msg.header.frame_id, msg.child_frame_id) == (parent, child)


def test_floor_poses_move_between_map_and_odom_and_nowhere_else():
    from services.core.mounts import Geometry
    tree = Tree(FrameNames(), (1.0, 2.0, math.pi / 2), Geometry())
    assert tree.to_world("odom", (0.5, 0.0, 0.3)) == pytest.approx((1.0, 2.5, 0.3 + math.pi / 2))
    assert tree.to_world("map", (0.5, 0.0, 0.3)) == pytest.approx((0.5, 0.0, 0.3))
    assert tree.from_world("odom", tree.to_world("odom", (0.2, -0.4, 1.0))) == pytest.approx(
        (0.2, -0.4, 1.0))
    with pytest.raises(UnknownFrameError, match="frame 'base_link' is not one the bridge"):
        tree.to_world("base_link", (0.0, 0.0, 0.0))
    with pytest.raises(UnknownFrameError, match="no frame_id"):
        tree.from_world("", (0.0, 0.0, 0.0))


def test_odometry_of_another_body_is_refused_naming_its_child_frame():
    from services.core.mounts import Geometry
    tree = Tree(FrameNames(), (1.0, 2.0, math.pi / 2), Geometry())
    T = rmw.typestore().types

    def odometry(child: str):  # type: ignore[no-untyped-def]
        return T[convert.ODOMETRY](
            header=convert.header(42, "odom"), child_frame_id=child,
            pose=T["geometry_msgs/msg/PoseWithCovariance"](
                pose=T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](x=0.5, y=0.0, z=0.0),
                    orientation=convert.yaw_quaternion(0.3)), covariance=np.zeros(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](
                    linear=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                    angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)),
                covariance=np.zeros(36)))
    for child in ("base_link", ""):  # the robot's base, or not said
        pose = convert.odometry_to_camera_pose(odometry(child), tree)
        assert (pose.x, pose.y) == pytest.approx((1.0, 2.5))
    with pytest.raises(UnknownFrameError, match=r"odometry of 'base_footprint'.*base_frame = "):
        convert.odometry_to_camera_pose(odometry("base_footprint"), tree)


def test_settings_keep_one_tree():
    from pydantic import ValidationError

    from services.ros2_bridge.service import Settings
    with pytest.raises(ValidationError, match="each frame needs its own name"):
        Settings(base_frame="odom")
    with pytest.raises(ValidationError, match="goal_frame 'base_link' must be"):
        Settings(goal_frame="base_link")
    assert Settings(goal_frame="odom").frame_names().world == "map"


async def _ros_tokens(ros: zenoh.Session, *parts: str, timeout: float = 30.0) -> list[str]:
    """The bridge's ROS 2 liveliness tokens once one holds each of ``parts`` (the bridge
    declares them as it starts; a loaded machine takes its time)."""
    deadline = time.monotonic() + timeout
    while True:
        tokens = [str(r.ok.key_expr) for r in await asyncio.to_thread(
            lambda: list(ros.liveliness().get("@ros2_lv/0/**", timeout=5.0))) if r.ok]
        missing = [p for p in parts if not any(p in t for t in tokens)]
        if not missing:
            return tokens
        if time.monotonic() > deadline:
            pytest.fail(f"no ROS 2 token with {missing} in {timeout:.0f} s: {tokens}")
        await asyncio.sleep(0.05)


def _pose(x: float, y: float, yaw: float, stamp: int) -> HumanoidPose:
    cov = ((1e-4, 2e-5, 3e-6), (2e-5, 4e-4, 5e-6), (3e-6, 5e-6, 6e-3))
    return HumanoidPose(seq=3, stamp_ns=stamp, x=x, y=y, yaw=yaw, covariance=cov,
                        marker_in_camera=MarkerInCamera(position=(0, 0, 0.3),
                                                        quaternion=(0, 0, 0, 1)),
                        reprojection_px=0.1)


def test_what_the_bridge_publishes_decodes_in_rosbags_to_the_same_values(router, make_bus,
                                                                         sessions):
    dep = parse_deployment({"zenoh": {"connect": [router], "multicast_scouting": False},
                            "services": {"ros2_bridge": {"goal_topic": "/goal_pose"}}})
    bus = make_bus("shepherd")
    ros = sessions()
    samples: list[tuple[str, bytes, bytes]] = []
    sub = ros.declare_subscriber("0/**", lambda s: samples.append((
        str(s.key_expr), s.payload.to_bytes(), s.attachment.to_bytes() if s.attachment else b"")))
    stamp = 1_700_000_000_123_456_789

    async def go() -> list[str]:
        task = asyncio.create_task(run_deployment(dep, duration=60))
        await wait_alive_async(bus.session, "ros2_bridge")
        tokens = await _ros_tokens(ros, "/NN/", "%humanoid%pose/", "/MS/%/%/shepherd_bridge/%odom/",
                                   "%goal_pose/")
        for suffix in (HUMANOID_POSE, CAMERA_GOAL):
            await wait_matched(bus, suffix)

        async def until(count: int, topic: str = "0/shepherd/humanoid/pose") -> None:
            await wait_for(lambda: sum(k.startswith(topic) for k, _, _ in samples) >= count,
                           f"{count} samples on {topic}")

        bus.put(HUMANOID_POSE, _pose(0.6, -0.2, 0.5, stamp))
        bus.put(CAMERA_GOAL, CameraGoal(stamp_ns=stamp, x=0.3, y=0.1, yaw=-1.0, reason="d"))
        bus.put(ODOM, CameraPose(stamp_ns=stamp, x=0.05, y=0.0, yaw=0.25))
        await until(1)
        await until(1, "0/goal_pose")
        bus.put(HUMANOID_POSE, _pose(0.61, -0.2, 0.5, stamp + 1))
        await until(2)
        await until(2, "0/tf/")
        task.cancel()
        return tokens
    tokens = asyncio.run(go())
    sub.undeclare()
    by_topic: dict[str, list[tuple[bytes, bytes]]] = {}
    for key, payload, attachment in samples:
        by_topic.setdefault(key.split("/geometry_msgs")[0].split("/tf2_msgs")[0], []).append(
            (payload, attachment))
    zid = tokens[0].split("/")[2]
    assert f"@ros2_lv/0/{zid}/0/0/NN/%/%/shepherd_bridge" in tokens
    assert any("/MP/%/%/shepherd_bridge/%shepherd%humanoid%pose/geometry_msgs::msg::dds_::"
               "PoseWithCovarianceStamped_/RIHS01_" in t for t in tokens)
    assert any("/MS/%/%/shepherd_bridge/%odom/nav_msgs::msg::dds_::Odometry_/" in t
               for t in tokens)
    assert any("/MP/%/%/shepherd_bridge/%goal_pose/geometry_msgs::msg::dds_::PoseStamped_/"
               in t for t in tokens)

    (payload, attachment), second = by_topic["0/shepherd/humanoid/pose"][:2]
    pose = rmw.deserialize(payload, convert.POSE_COV)
    assert pose.header.frame_id == "map" and convert.stamp_ns(pose.header.stamp) == stamp
    p, q = pose.pose.pose.position, pose.pose.pose.orientation
    assert (p.x, p.y, p.z) == pytest.approx((0.6, -0.2, 0.0))
    assert convert.quaternion_yaw(q) == pytest.approx(0.5)
    cov = np.array(pose.pose.covariance).reshape(6, 6)
    assert cov[0, 0] == 1e-4 and cov[0, 1] == 2e-5 and cov[0, 5] == 3e-6
    assert cov[1, 1] == 4e-4 and cov[5, 1] == 5e-6 and cov[5, 5] == 6e-3
    seq, source_ns, gid = rmw.unpack_attachment(attachment)
    assert rmw.unpack_attachment(second[1])[0] == seq + 1
    pose_token = next(t for t in tokens if "/MP/" in t and "%humanoid%pose/" in t)
    assert gid == rmw.entity_gid(pose_token)
    assert abs(source_ns - time.time_ns()) < 60e9

    goal = rmw.deserialize(by_topic["0/goal_pose"][0][0], convert.POSE)
    assert (goal.pose.position.x, goal.pose.position.y) == pytest.approx((0.3, 0.1))
    assert convert.quaternion_yaw(goal.pose.orientation) == pytest.approx(-1.0)

    frames = {}
    for payload, _ in by_topic["0/tf"]:
        for t in rmw.deserialize(payload, convert.TF).transforms:
            frames[(t.header.frame_id, t.child_frame_id)] = t
    assert frames[("map", "humanoid")].transform.translation.x == pytest.approx(0.61)  # latest
    # the camera robot's odometry is the robot's to publish (odom -> base_link), not ours
    assert set(frames) == {("map", "humanoid")}


def test_ros_odometry_and_goals_become_shepherd_messages(router, make_bus, sessions):
    dep = parse_deployment({"zenoh": {"connect": [router], "multicast_scouting": False},
                            "services": {"ros2_bridge": {
                                "T_world_odom": [1.0, 2.0, math.pi / 2],
                                "mission_goal_topic": "/shepherd/mission/goal"}}})
    bus = make_bus("shepherd")
    ros = sessions()
    ts = rmw.typestore()
    T = ts.types
    odom = T[convert.ODOMETRY](
        header=convert.header(1_700_000_000_000_000_042, "odom"), child_frame_id="base_link",
        pose=T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=0.5, y=0.0, z=0.0),
                orientation=convert.yaw_quaternion(0.3)), covariance=np.zeros(36)),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](linear=T["geometry_msgs/msg/Vector3"](
                x=0.0, y=0.0, z=0.0), angular=T["geometry_msgs/msg/Vector3"](
                x=0.0, y=0.0, z=0.0)), covariance=np.zeros(36)))
    def goal(frame: str) -> bytes:
        return rmw.serialize(T[convert.POSE](
            header=convert.header(5, frame), pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=0.9, y=-0.1, z=0.0),
                orientation=convert.yaw_quaternion(0.0))), convert.POSE)

    goal_key = rmw.data_key(0, "/shepherd/mission/goal", convert.POSE)

    async def go() -> tuple[CameraPose, MissionGoal, MissionGoal, ServiceStats]:
        odoms = bus.subscribe(ODOM, CameraPose, latest=False, queue=4)
        missions = bus.subscribe(MISSION_GOAL, MissionGoal, latest=False, queue=4)
        task = asyncio.create_task(run_deployment(dep, duration=60))
        await wait_alive_async(bus.session, "ros2_bridge")
        odom_key = rmw.data_key(0, "/odom", convert.ODOMETRY)
        for key in (odom_key, goal_key):  # the bridge's ROS subscriptions reached ``ros``
            await wait_matched_key(ros, key)
        gid = bytes(16)
        ros.put(odom_key, rmw.serialize(odom, convert.ODOMETRY),
                attachment=rmw.pack_attachment(1, time.time_ns(), gid))
        for n, frame in enumerate(("map", "odom", "base_footprint")):
            ros.put(goal_key, goal(frame), attachment=rmw.pack_attachment(n + 1, time.time_ns(),
                                                                          gid))
        camera, in_map, in_odom = (await odoms.recv(timeout=30), await missions.recv(timeout=30),
                                   await missions.recv(timeout=30))
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:  # the third goal, refused, shows in the stats
            stats = await bus.get(f"{STATS}/ros2_bridge", ServiceStats)
            if stats and stats[0].rejected:
                break
            await asyncio.sleep(0.1)
        assert missions.get_nowait() is None  # the refused goal went nowhere
        task.cancel()
        return camera, in_map, in_odom, stats[0]
    camera, mission, mission_odom, stats = asyncio.run(go())
    # the odometry frame sits at (1, 2) turned 90°: (0.5, 0) in it is (1, 2.5) in the world
    assert (camera.x, camera.y) == pytest.approx((1.0, 2.5))
    assert camera.yaw == pytest.approx(0.3 + math.pi / 2)
    assert camera.stamp_ns == 1_700_000_000_000_000_042
    assert mission.waypoints == [(0.9, -0.1)]  # in map: the world as it stands
    (x, y), = mission_odom.waypoints  # in odom: (0.9, -0.1) turned 90° and moved to (1, 2)
    assert (x, y) == pytest.approx((1.1, 2.9))
    reasons = stats.rejected[goal_key]
    assert len(reasons) == 1 and "frame 'base_footprint'" in next(iter(reasons))


@pytest.mark.slow
def test_the_camera_image_and_its_info_reach_ros_rate_limited(router, make_bus, sessions):
    from services.core.camera import CameraModel
    from services.runtime.frames import encode_frame
    from tests.conftest import wait_matched
    dep = parse_deployment({"zenoh": {"connect": [router], "multicast_scouting": False},
                            "services": {"ros2_bridge": {"image": True, "image_hz": 4}}})
    bus = make_bus("camera")
    ros = sessions()
    got: dict[str, list[bytes]] = {"image": [], "info": []}
    sub = ros.declare_subscriber("0/shepherd/camera/**", lambda s: got[
        "image" if "CompressedImage" in str(s.key_expr) else "info"].append(
        s.payload.to_bytes()))
    image = np.full((480, 640, 3), (255, 0, 255), np.uint8)
    # the intrinsics were put before the bridge started: only the queryable has them now
    bus.declare_queryable("camera/intrinsics", CameraModel.paper().to_message)

    async def go() -> float:
        task = asyncio.create_task(run_deployment(dep, duration=60))
        await wait_alive_async(bus.session, "ros2_bridge")
        await wait_matched(bus, "camera/frame")
        t0 = time.monotonic()
        seq = 0
        # 30 fps for a second, and on until two images and the info came out (a loaded
        # machine's bridge may need longer for them)
        while time.monotonic() - t0 < 1.0 or len(got["image"]) < 2 or not got["info"]:
            if time.monotonic() - t0 > 30:
                pytest.fail(f"{len(got['image'])} images, {len(got['info'])} infos in 30 s")
            bus.put_frame(*encode_frame(image, seq, 1_700_000_000_000_000_000 + seq))
            seq += 1
            await asyncio.sleep(1 / 30)
        sending_s = time.monotonic() - t0
        await asyncio.sleep(0.3)
        task.cancel()
        return sending_s + 0.3
    window_s = asyncio.run(go())
    sub.undeclare()
    # about 4 a second, not 30: at most one per 1/4 s of the window they could come out in
    assert 2 <= len(got["image"]) <= 1 + 4 * window_s, (len(got["image"]), window_s)
    img = rmw.deserialize(got["image"][0], convert.IMAGE)
    assert img.format == "jpeg" and img.header.frame_id == "camera_optical_frame"
    decoded = cv2.imdecode(np.asarray(img.data), cv2.IMREAD_COLOR)
    assert decoded.shape == (480, 640, 3)
    info = rmw.deserialize(got["info"][-1], convert.CAMERA_INFO)
    assert (info.width, info.height) == (640, 480) and info.k[0] == pytest.approx(757.25)


def test_the_rviz2_view_shows_what_the_robot_deployment_publishes():
    import yaml

    from services.ros2_bridge.service import Settings
    from services.runtime.config import load_deployment
    root = Path(__file__).resolve().parent.parent
    view = yaml.safe_load((root / "deploy" / "ros2" / "shepherd.rviz").read_text())
    dep = load_deployment(root / "deploy" / "robot-ros2.toml")
    config = dep.settings_for("ros2_bridge")
    assert isinstance(config, Settings)
    ns = dep.namespace
    manager = view["Visualization Manager"]
    assert manager["Global Options"]["Fixed Frame"] == config.world_frame
    topics = {d["Class"].rsplit("/", 1)[1]: d["Topic"]["Value"] for d in manager["Displays"]
              if "Topic" in d}
    assert topics == {
        "PoseWithCovariance": config.pose_topic or f"/{ns}/humanoid/pose",
        "Pose": config.goal_topic, "Image": f"/{ns}/camera/image/compressed"}
    assert config.image
    tool, = (t for t in manager["Tools"] if t["Class"].endswith("SetGoal"))
    assert tool["Topic"]["Value"] == config.mission_goal_topic


def test_with_odom_tf_the_simulated_robot_joins_the_tree(router, make_bus, sessions):
    # the simulator's camera/odom is Shepherd's own: published as odom -> base_link, and no
    # odometry taken from ROS (nothing to re-publish)
    dep = parse_deployment({"zenoh": {"connect": [router], "multicast_scouting": False},
                            "services": {"ros2_bridge": {"odom_tf": True,
                                                         "T_world_odom": [1.0, 2.0, 0.5]}}})
    bus = make_bus("sim")
    ros = sessions()
    samples: list[bytes] = []
    sub = ros.declare_subscriber(rmw.data_key(0, "/tf", convert.TF),
                                 lambda s: samples.append(s.payload.to_bytes()))

    async def go() -> list[str]:
        task = asyncio.create_task(run_deployment(dep, duration=60))
        await wait_alive_async(bus.session, "ros2_bridge")
        await wait_matched(bus, ODOM)
        bus.put(ODOM, CameraPose(stamp_ns=7, x=1.5, y=2.0, yaw=0.25))
        await wait_for(lambda: samples, "odom -> base_link on /tf")
        tokens = [str(r.ok.key_expr) for r in await asyncio.to_thread(
            lambda: list(ros.liveliness().get("@ros2_lv/0/**", timeout=1.0))) if r.ok]
        task.cancel()
        return tokens
    tokens = asyncio.run(go())
    sub.undeclare()
    t, = rmw.deserialize(samples[0], convert.TF).transforms
    assert (t.header.frame_id, t.child_frame_id) == ("odom", "base_link")
    # (1.5, 2) in the world: 0.5 m along the world's x from odom's origin, seen from odom
    # (turned 0.5 rad); heading 0.25 - 0.5
    assert t.transform.translation.x == pytest.approx(0.5 * math.cos(0.5))
    assert t.transform.translation.y == pytest.approx(-0.5 * math.sin(0.5))
    assert convert.quaternion_yaw(t.transform.rotation) == pytest.approx(-0.25)
    assert not any("/MS/" in k and "/%odom/" in k for k in tokens)


def test_a_late_rmw_zenoh_subscriber_gets_tf_static_from_the_cache(router, make_bus, sessions):
    # as rmw_zenoh subscribes to a transient-local topic: a zenoh-ext advanced subscriber that
    # detects late publishers, queries their history and follows their heartbeat
    import zenoh.ext
    dep = parse_deployment({"zenoh": {"connect": [router], "multicast_scouting": False},
                            "services": {"ros2_bridge": {}}})
    bus = make_bus("shepherd")
    ros = sessions()
    got: list[bytes] = []

    async def go() -> None:
        task = asyncio.create_task(run_deployment(dep, duration=15))
        await wait_alive_async(bus.session, "ros2_bridge")
        await asyncio.sleep(0.3)  # well after the bridge sent /tf_static
        sub = zenoh.ext.declare_advanced_subscriber(
            ros, rmw.data_key(0, "/tf_static", convert.TF),
            lambda s: got.append(s.payload.to_bytes()),
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
            recovery=zenoh.ext.RecoveryConfig(periodic_queries=None, heartbeat=True),
            subscriber_detection=True)
        await wait_for(lambda: got, "/tf_static from the bridge's cache")
        sub.undeclare()
        task.cancel()
    asyncio.run(go())
    assert len(got) == 1
    edges = [(t.header.frame_id, t.child_frame_id)
             for t in rmw.deserialize(got[0], convert.TF).transforms]
    assert edges == [("map", "odom"), ("base_link", "camera_link"),
                     ("camera_link", "camera_optical_frame")]
