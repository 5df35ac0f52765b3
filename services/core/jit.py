"""numba's ``njit`` with an on-disk cache that is safe across edits.

numba checks only the decorated function's own file when it reuses a cached machine-code
version, so a kernel that calls a kernel from another file could run stale code after an
edit. All kernel modules therefore share one cache directory named by a hash of all their
sources: any edit to any of them starts a fresh cache (a full compile, about 40 s).

The cache is set up by :func:`configure_cache`, which :func:`njit` calls before it defines
the first kernel (numba reads the directory when a kernel is defined, so it cannot wait for
the first call). ``NUMBA_CACHE_DIR`` in the environment wins over it.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba

#: The ``services`` package folder, against which kernel sources are named.
PACKAGE_ROOT = Path(__file__).resolve().parent.parent
#: Every module that defines an ``@njit`` kernel (tests check that none is missing).
KERNEL_SOURCES = ("core/jit.py", "core/order.py", "core/projection.py",
                  "vertex_extractor/colour.py",
                  "vertex_extractor/shape.py",
                  "vertex_extractor/scan.py", "vertex_extractor/lines.py",
                  "vertex_extractor/measure.py", "vertex_extractor/profile.py",
                  "vertex_extractor/covariance.py", "vertex_extractor/quad_model.py",
                  "vertex_extractor/paper.py", "vertex_extractor/recover.py",
                  "pose_estimator/p4p.py", "pose_estimator/estimate.py")

_configured: Path | None = None


def cache_tag(root: Path = PACKAGE_ROOT, sources: tuple[str, ...] = KERNEL_SOURCES) -> str:
    """The cache directory's name: numba's version and a hash of all kernel sources."""
    digest = hashlib.sha256()
    for name in sources:
        digest.update((root / name).read_bytes())
    return f"numba-{numba.__version__}-{digest.hexdigest()[:16]}"


def cache_dir(root: Path = PACKAGE_ROOT) -> Path:
    """Where the kernels are cached: ``<package>/__pycache__/<tag>`` when writable, else
    ``$XDG_CACHE_HOME/shepherd/<tag>``. Caches of earlier sources there are removed."""
    tag = cache_tag(root)
    for parent in (root / "__pycache__", Path(os.environ.get(
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
    return root / "__pycache__" / tag


def configure_cache() -> Path:
    """Point numba's cache at :func:`cache_dir` (once; ``NUMBA_CACHE_DIR`` wins)."""
    global _configured
    if _configured is None:
        env = os.environ.get("NUMBA_CACHE_DIR")
        _configured = Path(env) if env else cache_dir()
        numba.config.CACHE_DIR = str(_configured)
    return _configured


def njit(*args: Any, **kwargs: Any) -> Callable[..., Any]:
    """``numba.njit`` with ``cache=True`` in the shared cache."""
    configure_cache()
    kwargs.setdefault("cache", True)
    return numba.njit(*args, **kwargs)  # type: ignore[no-any-return]
