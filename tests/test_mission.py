"""The whole loop in simulation: the default mission, the course, the split deployment."""

import contextlib
import re
import signal
import socket
from pathlib import Path

import pytest

from tests.conftest import ROOT, endpoint, spawn_cli, wait_until

# end-to-end: left out of `make test-fast`; in real time, so `make test` runs it on the
# worker of the other real-time tests, one after another
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("realtime")]


def _final_error_cm(out: str) -> float:
    m = re.search(r"final error\s+([\d.]+) cm \(truth\)", out)
    assert m, out
    return float(m.group(1))


def test_default_mission_reaches_the_goal_within_3_cm(tmp_path: Path):
    """The stepping humanoid, calibrated (not true) intrinsics, biased, noisy, late odometry."""
    proc = spawn_cli("--log-level", "WARNING", "run", "--listen", endpoint(), "--duration",
                     "90", cwd=tmp_path)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, out + err
    assert _final_error_cm(out) <= 3.0
    reversals = re.search(r"command reversals\s+(\d+)", out)
    assert reversals and int(reversals.group(1)) <= 3, out
    assert "paper (x, y, z) cm" in out and "reached (3.3, 4.8, 58.2)" in out
    runs = list((tmp_path / "runs").iterdir())
    assert len(runs) == 1
    csv = (runs[0] / "trajectory.csv").read_text().splitlines()
    assert csv[0].startswith("source,time_s,x_m") and len(csv) > 100
    assert (runs[0] / "fig9_distance.png").stat().st_size > 5000
    assert "poses/s" in err  # the live progress line


def test_course_around_an_obstacle_repositions_past_the_critical_angle(tmp_path: Path):
    proc = spawn_cli("--log-level", "WARNING", "run", str(ROOT / "deploy/sim-course.toml"),
                     "--listen", endpoint(), "--duration", "200", cwd=tmp_path)
    out, err = proc.communicate(timeout=240)
    assert proc.returncode == 0, out + err[-3000:]
    found = re.search(r"critical-angle holds (\d+)", out)
    assert found, out
    holds = int(found.group(1))
    assert holds >= 1
    assert _final_error_cm(out) <= 4.0


def test_split_deployment_through_a_router(tmp_path: Path):
    ep = endpoint()
    router = spawn_cli("router", "--listen", ep)
    try:
        host, port = ep.removeprefix("tcp/").rsplit(":", 1)

        def listening() -> bool:
            with contextlib.suppress(OSError), socket.create_connection((host, int(port)), 1):
                return True
            return False
        wait_until(listening, "the router listening")
        robot = spawn_cli("--log-level", "WARNING", "run", str(ROOT / "deploy/sim-robot.toml"),
                          "--connect", ep, "--processes", cwd=tmp_path)
        laptop = spawn_cli("--log-level", "WARNING", "run",
                           str(ROOT / "deploy/sim-laptop.toml"), "--connect", ep,
                           "--duration", "90", cwd=tmp_path)
        out, err = laptop.communicate(timeout=120)
        robot.send_signal(signal.SIGTERM)
        robot.communicate(timeout=10)
    finally:
        router.send_signal(signal.SIGINT)
        router.communicate(timeout=10)
    assert laptop.returncode == 0, out + err[-3000:]
    assert _final_error_cm(out) <= 3.0
    reversals = re.search(r"command reversals\s+(\d+)", out)
    assert reversals and int(reversals.group(1)) <= 3, out
