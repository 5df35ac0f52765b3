"""The compiled-kernel plumbing: the shared cache, `shepherd compile`, the event loop."""

import asyncio
import shutil
from pathlib import Path

from services import jit
from services.cli import _fast_event_loop
from tests.conftest import run_cli


def test_cache_tag_changes_when_any_kernel_source_changes(tmp_path: Path):
    for name in jit.KERNEL_SOURCES:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(jit._ROOT / name, tmp_path / name)
    before = jit.cache_tag(tmp_path)
    assert before == jit.cache_tag()  # the copy hashes like the package
    callee = tmp_path / "vertex_extractor" / "colour.py"  # called from scan.py
    callee.write_text(callee.read_text() + "\n# edited\n")
    assert jit.cache_tag(tmp_path) != before


def test_shepherd_compile_reports_both_kernel_groups():
    out = run_cli("compile")
    assert out.returncode == 0, out.stderr
    assert "compiling the vertex extractor kernels ... " in out.stdout
    assert "compiling the pose estimator kernels ... " in out.stdout


def test_the_cli_runs_on_uvloop():
    policy = asyncio.get_event_loop_policy()
    try:
        _fast_event_loop()
        assert type(asyncio.get_event_loop_policy()).__module__.startswith("uvloop")
    finally:
        asyncio.set_event_loop_policy(policy)
