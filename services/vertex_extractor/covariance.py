"""The vertex covariance a detection reports (issue 21): what the scans' line fits say, made
honest across marker sizes, plus what the marker's own profile says about a misplaced edge.

The line fits' covariance shrinks as 1/N with the N edge points, but the errors that matter
do not average out along an edge (shading, the demosaicing's and JPEG's blocks, a shadow's
boundary): taken as it is, a 150 px marker's vertices were 2-3 times less certain than
reported and a 30 px one's twice as certain. A shadow's boundary or a blur that moves an
edge leaves the lines straight and the two scans agreeing; the profile across the edges
(``profile.py``) shows it. The reported covariance, per vertex k:

    C_k = SCALE * (s / SIZE_PX) ** SIZE_POWER * C_scan_k
          + (FLOOR_PX2 + sum over the profile's figures x of (GAIN * max(x - DEAD_PX, 0))²) I

``C_scan``: the kernel's (the two scans' mean covariance and their disagreement, scaled:
``extractor.MEAN_COV_SCALE``, ``GAP_COV_SCALE``); s: the marker's size, √(2 · area) px (a
rhombus's diagonals' geometric mean); the profile's figures: how far (px) the edges next to
vertex k and the stretches of them nearest to it cross half way off the median of the
others, and how far the four edges' median crossing is off the fitted lines (a blur seen by
all four alike).

Calibrated on webcam renders under every hard condition (``services/sim/scenes.py``) so
that the squared vertex errors normalised by it average 2 (1.7-2.6 per condition on
held-out renders). The shape test (``shape.py``) weighs the vertices by the kernel's
covariance, as it was tuned: a vertex's profile term there would let it pass a marker whose
*neighbouring* vertex is px off. Compiled (a tracked frame's budget is 0.1 ms), no bus.
"""

from __future__ import annotations

import math

import numpy as np

from services.core.jit import njit

SCALE = 0.36         # the scans' covariance at SIZE_PX
SIZE_PX = 70.0       # px
SIZE_POWER = 0.55    # how it grows with the marker's size
FLOOR_PX2 = 0.002    # a vertex is never known better than about 0.045 px
GAIN = 3.0           # px of vertex uncertainty per px of profile offset beyond DEAD_PX
DEAD_PX = 0.15       # an edge's or stretch's offset from the others' this small is noise
COMMON_DEAD_PX = 0.12  # the four edges' median offset this small is noise


@njit(inline="always")
def size_px(v: np.ndarray) -> float:
    """√(2 · area) (px) of the quadrilateral v (4, 2) px: its diagonals' geometric mean."""
    return math.sqrt(abs((v[2, 0] - v[0, 0]) * (v[3, 1] - v[1, 1])
                         - (v[2, 1] - v[0, 1]) * (v[3, 0] - v[1, 0])))


@njit(inline="always")
def _excess(x: float, dead: float) -> float:
    return (GAIN * max(x - dead, 0.0)) ** 2


@njit(inline="always")
def _median_dev(x: np.ndarray, out: np.ndarray) -> float:
    """out = |x - median(x)| (NaN counted as 0 for the median, its deviation 0); the median."""
    m = np.sort(np.where(np.isnan(x), 0.0, x))
    n = m.shape[0]
    median = 0.5 * (m[n // 2 - 1] + m[n // 2])
    for i in range(n):
        out[i] = 0.0 if math.isnan(x[i]) else abs(x[i] - median)
    return median


@njit()
def profile_px2(edge_offsets_px: np.ndarray, vertex_steps_px: np.ndarray) -> np.ndarray:
    """Each vertex's (4) variance px², each way, from the profile across its edges (the
    floor included): ``profile.examine``'s edge offsets (4: edge k from vertex k to k + 1)
    and ``profile.vertex_steps`` (8: edge k next to vertex k, then edge k next to vertex k + 1;
    NaN where unknown)."""
    edge_dev = np.empty(4)
    step_dev = np.empty(8)
    median = _median_dev(edge_offsets_px, edge_dev)
    _median_dev(vertex_steps_px, step_dev)
    common = FLOOR_PX2 + _excess(abs(median), COMMON_DEAD_PX)
    out = np.empty(4)
    for k in range(4):
        j = (k + 3) % 4  # the edge that ends at vertex k
        out[k] = common + _excess(max(edge_dev[k], edge_dev[j]), DEAD_PX) + _excess(
            max(step_dev[k], step_dev[4 + j]), DEAD_PX)
    return out


@njit()
def reported(v: np.ndarray, scan_cov_px2: np.ndarray, edge_offsets_px: np.ndarray,
             vertex_steps_px: np.ndarray) -> np.ndarray:
    """The covariance (4, 2, 2) px² reported with vertices v (4, 2) px (L, T, R, B), from the
    kernel's ``scan_cov_px2`` (4, 2, 2) and the profile (``profile_px2``)."""
    iso = profile_px2(edge_offsets_px, vertex_steps_px)
    out = SCALE * (size_px(v) / SIZE_PX) ** SIZE_POWER * scan_cov_px2
    for k in range(4):
        out[k, 0, 0] += iso[k]
        out[k, 1, 1] += iso[k]
    return out


def warm_up() -> None:
    """Compile (or load) the kernel."""
    reported(np.array([[10.0, 20.0], [20.0, 10.0], [30.0, 20.0], [20.0, 30.0]]),
             np.tile(np.eye(2), (4, 1, 1)), np.zeros(4), np.zeros(8))
