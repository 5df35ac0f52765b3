"""The compiled-kernel plumbing: the shared cache, `shepherd compile`, the event loop, the
kernels' in-place median."""

import asyncio
import shutil
from pathlib import Path

import numpy as np

from services.core import jit
from services.core.order import IN_PLACE_MAX, median_in_place
from services.tools.cli import use_fast_event_loop
from tests.conftest import run_cli


def test_cache_tag_changes_when_any_kernel_source_changes(tmp_path: Path):
    for name in jit.KERNEL_SOURCES:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(jit.PACKAGE_ROOT / name, tmp_path / name)
    before = jit.cache_tag(tmp_path)
    assert before == jit.cache_tag()  # the copy hashes like the package
    callee = tmp_path / "vertex_extractor" / "colour.py"  # called from scan.py
    callee.write_text(callee.read_text() + "\n# edited\n")
    assert jit.cache_tag(tmp_path) != before


def test_every_module_with_a_kernel_is_in_the_cache_key():
    defining = {str(p.relative_to(jit.PACKAGE_ROOT)) for p in jit.PACKAGE_ROOT.rglob("*.py")
                if "@njit" in p.read_text() or p.name == "jit.py"}
    assert defining == set(jit.KERNEL_SOURCES), (
        f"missing from KERNEL_SOURCES: {sorted(defining - set(jit.KERNEL_SOURCES))}; "
        f"listed without a kernel: {sorted(set(jit.KERNEL_SOURCES) - defining)}")


def test_the_kernel_cache_is_the_tagged_directory(monkeypatch, tmp_path: Path):
    monkeypatch.setattr(jit, "_configured", None)
    monkeypatch.setattr(jit.numba.config, "CACHE_DIR", "")
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    assert jit.configure_cache().name == jit.cache_tag()
    assert jit.numba.config.CACHE_DIR == str(jit.configure_cache())
    monkeypatch.setattr(jit, "_configured", None)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert jit.configure_cache() == tmp_path  # the user's choice wins


def test_shepherd_compile_reports_both_kernel_groups():
    out = run_cli("compile")
    assert out.returncode == 0, out.stderr
    assert "compiling the vertex extractor kernels ... " in out.stdout
    assert "compiling the pose estimator kernels ... " in out.stdout


def test_the_cli_runs_on_uvloop():
    policy = asyncio.get_event_loop_policy()
    try:
        use_fast_event_loop()
        assert type(asyncio.get_event_loop_policy()).__module__.startswith("uvloop")
    finally:
        asyncio.set_event_loop_policy(policy)


def test_the_median_in_place_is_numpys_median():
    """``order.median_in_place`` (the profile's and line fits' medians): the same number as
    ``np.median`` for short arrays sorted in place and for long ones handed to numpy."""
    rng = np.random.default_rng(4)
    for n in range(1, IN_PLACE_MAX + 12):
        for values in (rng.normal(size=n), np.round(rng.normal(size=n)), np.zeros(n)):
            scratch = np.concatenate([values, [np.inf]])  # only a[:n] is read
            assert median_in_place(scratch, n) == np.median(values), (n, values)
