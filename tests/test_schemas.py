import json
import math

import pytest
from pydantic import ValidationError

from schemas import (
    ALL_MODELS,
    TOPICS,
    CameraIntrinsics,
    Command,
    FrameHeader,
    HumanoidPose,
    IrCommand,
    Keys,
    MarkerVertices,
    model_for,
)
from tests.conftest import cli_here, run_cli

K = ((757.25, 2.06, 389.67), (0.0, 754.24, 260.5), (0.0, 0.0, 1.0))


def test_ir_command_fills_the_robosapien_code():
    assert IrCommand(command="walk_forward").code == 0x86
    assert IrCommand(command=Command.STOP).code == 0x8E
    with pytest.raises(ValidationError, match="command"):
        IrCommand(command="dance")


def test_floats_must_be_finite():
    with pytest.raises(ValidationError, match="finite"):
        MarkerVertices(seq=0, stamp_ns=0, found=True,
                       vertices_px=((math.nan, 0), (1, 1), (2, 2), (3, 3)))


def test_exactly_four_vertices():
    with pytest.raises(ValidationError, match="vertices_px"):
        MarkerVertices(seq=0, stamp_ns=0, found=True, vertices_px=((0, 0), (1, 1), (2, 2)))


def test_intrinsics_K_is_a_camera_matrix():
    CameraIntrinsics(width=640, height=480, K=K)
    with pytest.raises(ValidationError, match="upper triangular"):
        CameraIntrinsics(width=640, height=480, K=((1, 0, 0), (1, 1, 0), (0, 0, 1)))
    with pytest.raises(ValidationError, match="K"):
        CameraIntrinsics(width=640, height=480, K=((1, 0, 0), (0, 1, 0)))


def test_messages_are_frozen_and_round_trip():
    m = HumanoidPose(seq=3, stamp_ns=5, x=0.3, y=0.0, yaw=0.1,
                     marker_in_camera={"position": (0, 0, 0.25), "quaternion": (0, 0, 0, 1)},
                     reprojection_px=0.1)
    with pytest.raises(ValidationError):
        m.x = 1.0  # type: ignore[misc]
    assert HumanoidPose.model_validate_json(m.model_dump_json()) == m
    assert HumanoidPose.zenoh_encoding() == "application/json;shepherd.HumanoidPose/1"


def test_frame_header_expected_size():
    h = FrameHeader(seq=0, stamp_ns=0, width=640, height=480, encoding="bgr8")
    assert h.expected_size() == 640 * 480 * 3
    assert FrameHeader(seq=0, stamp_ns=0, width=4, height=2, encoding="jpeg").expected_size() \
        is None


def test_key_table():
    keys = Keys("lab/robot1")
    assert keys.key("humanoid/pose") == "lab/robot1/humanoid/pose"
    assert keys.alive("sim") == "lab/robot1/alive/sim"
    assert keys.suffix("lab/robot1/camera/frame") == "camera/frame"
    assert model_for("ir/command") is IrCommand
    with pytest.raises(KeyError, match="unknown topic"):
        model_for("nope")
    with pytest.raises(ValueError, match="namespace"):
        Keys("bad/*")


def test_shepherd_schemas_prints_every_model():
    out = cli_here("schemas")
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    for model in ALL_MODELS:
        assert data[model.__name__]["encoding"] == model.zenoh_encoding()
        assert "properties" in data[model.__name__]["schema"]
    assert set(data["_keys"]) == set(TOPICS)


def test_version():
    out = run_cli("--version")
    assert out.returncode == 0 and out.stdout.startswith("shepherd ")
