"""numba's ``njit`` with an on-disk cache that is safe across edits.

numba checks only the decorated function's own file when it reuses a cached machine-code
version, so a kernel that calls a kernel from another file could run stale code after an
edit. All kernel modules therefore share one cache directory named by a hash of all their
sources: any edit to any of them starts a fresh cache (a full compile, about 40 s).
"""

from __future__ import annotations

import hashlib
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba

_ROOT = Path(__file__).resolve().parent
KERNEL_SOURCES = ("jit.py", "projection.py", "vertex_extractor/colour.py",
                  "vertex_extractor/scan.py", "vertex_extractor/lines.py",
                  "pose_estimator/p4p.py", "pose_estimator/estimate.py")


def cache_tag(root: Path = _ROOT, sources: tuple[str, ...] = KERNEL_SOURCES) -> str:
    """The cache directory's name: numba's version and a hash of all kernel sources."""
    digest = hashlib.sha256()
    for name in sources:
        digest.update((root / name).read_bytes())
    return f"numba-{numba.__version__}-{digest.hexdigest()[:16]}"


def _cache_dir() -> Path:
    tag = cache_tag()
    for parent in (_ROOT / "__pycache__", Path(os.environ.get(
            "XDG_CACHE_HOME", Path.home() / ".cache")) / "shepherd"):
        try:
            parent.mkdir(parents=True, exist_ok=True)
            if os.access(parent, os.W_OK):
                for old in parent.glob("numba-*"):  # caches of earlier sources
                    if old.name != tag:
                        shutil.rmtree(old, ignore_errors=True)
                return parent / tag
        except OSError:
            continue
    return _ROOT / "__pycache__" / tag


if not os.environ.get("NUMBA_CACHE_DIR"):
    numba.config.CACHE_DIR = str(_cache_dir())


def njit(*args: Any, **kwargs: Any) -> Callable[..., Any]:
    """``numba.njit`` with ``cache=True``."""
    kwargs.setdefault("cache", True)
    return numba.njit(*args, **kwargs)
