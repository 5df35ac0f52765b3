"""An installed wheel, not the source tree: ``shepherd run`` from an empty folder works, with
the default deployment and the paper's camera shipped as package data."""

from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from tests.conftest import endpoint

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
def test_a_wheel_installed_elsewhere_runs_the_default_mission_from_an_empty_folder(
        tmp_path: Path):
    dist = tmp_path / "dist"
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w",
                            str(dist), str(ROOT)], capture_output=True, text=True, timeout=300)
    assert built.returncode == 0, built.stderr[-3000:]
    wheel = next(dist.glob("shepherd-*.whl"))
    # a fresh venv whose dependencies come from this one (no download), the wheel its own
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    purelib = Path(subprocess.run(
        [venv / "bin" / "python", "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
        capture_output=True, text=True, check=True).stdout.strip())
    (purelib / "deps.pth").write_text(sysconfig.get_path("purelib") + "\n")
    installed = subprocess.run([sys.executable, "-m", "pip", "--python", str(venv / "bin" /
                                "python"), "install", "--no-deps", "-q", str(wheel)],
                               capture_output=True, text=True, timeout=300)
    assert installed.returncode == 0, installed.stderr[-3000:]
    empty = tmp_path / "elsewhere"
    empty.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "NUMBA_CACHE_DIR")}
    shepherd = str(venv / "bin" / "shepherd")
    where = subprocess.run([venv / "bin" / "python", "-c",
                            "import services.data as d; print(d.DEFAULT_DEPLOYMENT)"],
                           capture_output=True, text=True, cwd=empty, env=env, check=True)
    assert where.stdout.strip().startswith(str(purelib)), where.stdout  # not the source tree
    # (a fresh cache: 40 s to 6 min for the kernels with the other test worker busy, by the
    # machine and the day; the test asks for a compile that works, not for its time)
    compiled = subprocess.run([shepherd, "compile"], capture_output=True, text=True,
                              cwd=empty, env=env, timeout=1500)
    assert compiled.returncode == 0, compiled.stderr[-3000:]
    # 10 s: the services' start (kernels loaded from the cache) takes a few seconds of it on
    # a busy machine; the test asks for poses, not for a start-up time
    run = subprocess.run([shepherd, "--log-level", "WARNING", "run", "--duration", "10",
                          "--listen", endpoint()], capture_output=True,
                         text=True, cwd=empty, env=env, timeout=120)
    assert run.returncode == 0, run.stderr[-3000:]
    trajectories = list((empty / "runs").glob("*/trajectory.csv"))
    assert trajectories, f"no run folder in {empty}: {run.stdout[-2000:]}"
    rows = trajectories[0].read_text().splitlines()
    estimates = [r for r in rows if r.startswith("estimate,")]
    assert len(estimates) > 20, run.stdout[-2000:] + run.stderr[-2000:]  # poses recorded

