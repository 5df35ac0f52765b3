"""An installed wheel, not the source tree: ``shepherd run`` from an empty folder works, with
the default deployment and the paper's camera shipped as package data."""

from __future__ import annotations

import importlib
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from numba.core.caching import UserProvidedCacheLocator

from services.core import jit
from tests.conftest import endpoint

ROOT = Path(__file__).resolve().parent.parent


def _seed_kernel_cache(installed: Path) -> int:
    """This tree's compiled kernels (``make install`` compiled them: the same sources) copied
    to where the installed package ``installed`` looks for them; how many folders. numba
    checks a cached kernel's source by its content, so the installed copy's kernels load
    from them; any it lacks are compiled there (the test asks for a compile that works; a
    fresh compile of the same sources is ``make install``'s, 4-8 minutes of this test
    before)."""
    mine = jit.configure_cache()
    target = installed / "__pycache__" / mine.name  # (jit.cache_dir: the same tag)
    copied = 0
    folder = UserProvidedCacheLocator.get_suitable_cache_subpath  # (numba's: by a file's folder)
    for sub in {Path(name).parent.name for name in jit.KERNEL_SOURCES}:
        package = importlib.import_module(f"services.{sub}")  # (numba's path: not resolved)
        cached = mine / folder(str(package.__file__))
        if cached.is_dir():
            shutil.copytree(cached, target / folder(str(installed / sub / "__init__.py")))
            copied += 1
    return copied


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
    seeded = _seed_kernel_cache(purelib / "services")  # (0: compiled afresh, minutes)
    compiled = subprocess.run([shepherd, "compile"], capture_output=True, text=True,
                              cwd=empty, env=env, timeout=1500)
    assert compiled.returncode == 0, f"{seeded} cache folders seeded\n{compiled.stderr[-3000:]}"
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

