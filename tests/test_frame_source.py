"""The frame source: frames stamped when they were taken (and saying by which clock), camera
controls applied and read back, frame size and intrinsics kept consistent."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from schemas import CameraIntrinsics, FrameHeader
from schemas.keys import FRAME, INTRINSICS
from services.core.camera import CameraModel
from services.frame_source.service import Settings
from services.frame_source.sources import CONTROLS, apply_controls, fourcc_code, open_source
from services.runtime.config import ConfigError, parse_deployment
from services.runtime.launcher import run_deployment
from tests.conftest import wait_alive_async


def _video(path: Path, n: int = 12, fps: float = 10.0, size: tuple[int, int] = (64, 48)) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), fps, size)
    for i in range(n):
        writer.write(np.full((size[1], size[0], 3), 20 * i % 255, np.uint8))
    writer.release()
    return path


def test_a_video_file_gives_frames_stamped_from_the_file(tmp_path: Path):
    source = open_source(str(_video(tmp_path / "v.avi")), loop=False)
    assert source.stamp_source == "container"
    stamps = []
    for _ in range(6):  # read much faster than the file's 10 fps
        frame = source.read()
        assert frame.stamp_source == "container"
        stamps.append(frame.stamp_ns)
    source.close()
    assert np.diff(stamps) == pytest.approx([100_000_000] * 5, abs=1_000_000)


def test_the_service_publishes_file_stamps_and_scaled_intrinsics(tmp_path: Path, router,
                                                                 make_bus):
    # 60 frames paced at 10 fps: the service lives 6 s, then ends with its file (and with it
    # its liveliness token and the intrinsics queryable); at 50 fps its 0.8 s could pass on a
    # loaded machine before the watcher looked
    video = _video(tmp_path / "v.avi", n=60, size=(128, 96))
    (tmp_path / "cam.toml").write_text(CameraModel.paper().to_toml())  # calibrated at 640x480
    dep = parse_deployment({"zenoh": {"connect": [router], "multicast_scouting": False},
                            "services": {"frame_source": {
                                "source": str(video), "fps": 10, "loop": False,
                                "width": 320, "height": 240, "intrinsics": "cam.toml"}}},
                           tmp_path / "d.toml")
    bus = make_bus("watcher")
    headers: list[FrameHeader] = []
    sub = bus.session.declare_subscriber(bus.keys.key(FRAME), lambda s: headers.append(
        FrameHeader.model_validate_json(s.attachment.to_bytes())))

    async def go() -> list[CameraIntrinsics]:
        task = asyncio.create_task(run_deployment(dep, duration=10))
        await wait_alive_async(bus.session, "frame_source")
        deadline = time.monotonic() + 30
        while not (got := await bus.get(INTRINSICS, CameraIntrinsics, timeout=2)):
            assert time.monotonic() < deadline, "the intrinsics queryable never answered"
            await asyncio.sleep(0.05)
        await task
        return got
    intrinsics = asyncio.run(go())
    sub.undeclare()
    assert len(headers) >= 10
    assert {h.stamp_source for h in headers} == {"container"}
    assert {(h.width, h.height) for h in headers} == {(320, 240)}
    gaps = np.diff([h.stamp_ns for h in headers[:10]])
    assert gaps == pytest.approx([100_000_000] * len(gaps), abs=1_000_000)  # the file's 10 fps
    k = intrinsics[0]
    assert (k.width, k.height) == (320, 240)
    assert k.K[0][0] == pytest.approx(757.25 / 2) and k.K[0][2] == pytest.approx(
        (389.67 + 0.5) / 2 - 0.5)


def test_an_image_folder_is_stamped_when_read(tmp_path: Path):
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((8, 8, 3), np.uint8))
    frame = open_source(str(tmp_path)).read()
    assert frame.stamp_source == "read" and frame.stamp_ns > 0


class FakeCamera:
    """A device that takes some controls, rounds some and refuses others."""

    def __init__(self) -> None:
        self.props: dict[int, float] = {}

    def set(self, prop: int, value: float) -> bool:
        if prop == CONTROLS["focus"]:
            return False  # no focus motor
        if prop == CONTROLS["width"]:
            value = 1280.0  # only one mode
        if prop == CONTROLS["exposure"]:
            value = round(value / 10) * 10.0  # coarse steps
        self.props[prop] = value
        return True

    def get(self, prop: int) -> float:
        return self.props.get(prop, 0.0)


def test_camera_controls_are_applied_read_back_and_refusals_named():
    wanted = Settings(source="0", width=640, height=480, fps=30, fourcc="MJPG",
                      exposure=157.0, auto_exposure=1, autofocus=False, focus=20).controls()
    got, refused = apply_controls(FakeCamera(), wanted)
    assert refused == ["width", "exposure", "focus"]
    assert got["height"] == 480 and got["fourcc"] == fourcc_code("MJPG") and got["width"] == 1280
    assert list(got)[:4] == ["width", "height", "fps", "fourcc"]  # format before exposure


def test_width_without_height_is_an_error_naming_them(tmp_path: Path):
    with pytest.raises(ConfigError, match=r"services\.frame_source: width and height go "):
        parse_deployment({"services": {"frame_source": {"source": "0", "width": 640}}},
                         tmp_path / "d.toml")
    with pytest.raises(ValueError, match="fourcc must be 4 characters"):
        fourcc_code("MJPEG")


def test_resized_intrinsics_keep_the_projection_consistent():
    cam = CameraModel.paper()
    half = cam.resized(320, 240)
    p = np.array([[0.05, -0.02, 0.4], [-0.1, 0.03, 0.5]])
    full_px, half_px = cam.project(p), half.project(p)
    assert half_px == pytest.approx((full_px + 0.5) / 2 - 0.5)
