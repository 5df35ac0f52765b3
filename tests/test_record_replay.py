import asyncio
import contextlib
import json
from pathlib import Path

import pytest
from mcap.reader import make_reader

from schemas import HumanoidPose
from schemas.keys import HUMANOID_POSE
from services.runtime.config import parse_deployment
from services.runtime.launcher import run_deployment
from tests.conftest import (
    ROOT,
    run_cli,
    spawn_cli,
    wait_alive_async,
    wait_for,
    wait_matched_key,
)

pytestmark = pytest.mark.slow  # end-to-end: left out of `make test-fast`


def test_record_then_replay_frames_reproduces_the_poses(tmp_path: Path, router, make_bus,
                                                         sessions):
    live = parse_deployment({
        "zenoh": {"connect": [router], "multicast_scouting": False},
        # odometry with every frame, at once: the poses then depend on the recording alone
        "services": {"sim": {"intrinsics": str(ROOT / "deploy/paper-camera.toml"), "fps": 15,
                             "camera_robot": {"odom_hz": 15, "odom_latency_s": 0.0}},
                     "vertex_extractor": {},
                     "pose_estimator": {"intrinsics": str(ROOT / "deploy/paper-camera.toml")}}})
    rec_path = tmp_path / "run.mcap"
    # the recorder's duration runs from its subscription, which we wait for (not a sleep)
    recorder = spawn_cli("record", str(rec_path), "--connect", router, "--duration", "8")
    asyncio.run(wait_matched_key(sessions(), "shepherd/camera/frame"))
    asyncio.run(run_deployment(live, duration=4.0))
    _, err = recorder.communicate(timeout=30)
    assert recorder.returncode == 0, err
    recorded: dict[int, HumanoidPose] = {}
    topics = set()
    with open(rec_path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            topics.add(channel.topic)
            if channel.topic.endswith("humanoid/pose"):
                assert schema is not None
                assert schema.encoding == "jsonschema"
                assert "marker_in_camera" in json.loads(schema.data)["properties"]
                p = HumanoidPose.model_validate_json(message.data)
                recorded[p.seq] = p
    assert {"shepherd/camera/frame", "shepherd/humanoid/pose", "shepherd/sim/truth"} <= topics
    assert len(recorded) > 20

    offline = parse_deployment({
        "zenoh": {"connect": [router], "multicast_scouting": False},
        "services": {"vertex_extractor": {},
                     "pose_estimator": {"intrinsics": str(ROOT / "deploy/paper-camera.toml")}}})
    bus = make_bus("checker")

    async def go() -> dict[int, HumanoidPose]:
        poses = bus.subscribe(HUMANOID_POSE, HumanoidPose, latest=False, queue=1000)
        task = asyncio.create_task(run_deployment(offline, duration=20))
        await wait_alive_async(bus.session, "vertex_extractor", "pose_estimator")
        res = await asyncio.to_thread(run_cli, "replay", str(rec_path), "--connect", router,
                                      "--only", "shepherd/camera/frame", "--only",
                                      "shepherd/camera/odom", timeout=60)
        assert res.returncode == 0, res.stderr
        got: dict[int, HumanoidPose] = {}

        def enough() -> bool:  # the poses of the replayed frames may still be on their way
            while (p := poses.get_nowait()) is not None:
                got[p.seq] = p
            return len(set(recorded) & set(got)) >= 0.5 * len(recorded)
        with contextlib.suppress(pytest.fail.Exception):
            await wait_for(enough, "half the recorded poses replayed", timeout=15)
        task.cancel()
        return got
    replayed = asyncio.run(go())
    common = set(recorded) & set(replayed)
    assert len(common) >= 0.5 * len(recorded)
    for seq in common:
        a, b = recorded[seq], replayed[seq]
        assert b.x is not None and a.x is not None and a.y is not None and b.y is not None
        assert a.yaw is not None and b.yaw is not None
        assert abs(a.x - b.x) < 1e-6 and abs(a.y - b.y) < 1e-6 and abs(a.yaw - b.yaw) < 1e-6
        for u, v in zip(a.marker_in_camera.position, b.marker_in_camera.position, strict=True):
            assert abs(u - v) < 1e-9


def test_replay_of_a_missing_file_is_a_clear_error(tmp_path: Path):
    res = run_cli("replay", str(tmp_path / "nope.mcap"))
    assert res.returncode == 2 and "no such recording" in res.stderr
