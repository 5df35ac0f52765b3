"""The marker under a cast shadow, fitted whole to its pixels: the extractor's last resort
for a marker its scans refuse (issue 21; docs/measured.md "A model of the shadowed marker").

A cast shadow is one straight boundary across the marker and its surround that scales both
by one factor k. Its boundary inside the scans' window moves their sub-pixel edges, and the
profile test rightly refuses them. Here the marker's chroma score (``colour.py``'s vector,
taken from the marker's own centre) in its box plus ``MARGIN_PX`` is fitted as

    score(x, y) = b + A · Π_edges Φ(d_i / σ) · (k + (1 − k) · Φ(s / σ_s))

d_i: the signed distance (px) to edge i, inward; σ: the edges' blur (px); s: the signed
distance to the shadow's line (angle, ρ), lit side positive; σ_s: its softness (px). 15
parameters, fitted by Levenberg-Marquardt on a soft-L1 loss (``robust_lm``: the normal
equations, 15 x 15, where ``scipy.optimize.least_squares`` factors the whole Jacobian on every
step: the same optimum in 1.6 times the time, and its threaded SVD contends with other
processes), started from the scans' quadrilateral and from the best two-level split of the
interior's scores.

A fit is taken only if it is a shadow and nothing else (tuned on seeds 2024, 7 and 11, held
out on seeds 31-35 and other photographs): a shadow was found, 0.1 ≤ k ≤ 0.6; the surround
shows it too (across the fitted line, outside the marker, the median brightness ratio is at
most ``MAX_SURROUND_RATIO`` and within a factor of 2 of k, over ``MIN_SURROUND_PAIRS``
pairs); every edge's band fits within ``MAX_BAND_RMS`` of the marker's level; no vertex moved
more than ``MAX_SHIFT_PX``; and no clipped highlight is in the box. Its vertices' reported
sigma: ``SIGMA_SCALE`` times the fit's, with a floor ``SIGMA_FLOOR_PX`` (isotropic, px).

The same fit checks a marker the scans *found* but report unsure of, some vertex's sigma over
``CHECK_SIGMA_PX`` (the extractor's ``_checked_under_shadow``): started from their vertices,
a fit taken that puts a vertex more than ``CHECK_APART_PX`` from theirs refuses the marker (a
shadow's boundary moved their edges; neither is taken: the fit's vertices, where the scans
were right, were the wrong ones).

numpy, with the model compiled (``quad_model.py``): 17-20 ms a fitted view at the median,
35-46 ms at the 95th percentile (32-33 ms and 64-79 ms with the model in numpy); only views
every other route refused pay it, and most of those stop before fitting; as a check, a
found marker reporting a vertex over ``CHECK_SIGMA_PX`` (about 1 in 10 under a shadow: 20
ms at the median; elsewhere it mostly stops at its split, 2-5 ms).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from services.vertex_extractor import quad_model
from services.vertex_extractor.colour import chroma_direction

MARGIN_PX = 6            # the fitted box: the quadrilateral's plus this (px)
MAX_BOX_PX = 40_000      # a larger box is not fitted (its cost), px²
MIN_INTERIOR_PX = 20     # the interior's pixels a shadow's split needs
SPLIT_ANGLES_DEG = 4.0   # the interior's two-level split tried every this (deg)
MAX_SPLIT_RATIO = 0.8    # a split whose dark level is above this share of the lit one: none
MIN_K, MAX_K = 0.1, 0.6  # a shadow's darkening factor k that is taken
MAX_SURROUND_RATIO = 0.7  # the surround's shaded / lit brightness across the line, at most
MIN_SURROUND_PAIRS = 20  # pixel pairs across the line outside the marker, at least
SURROUND_REACH_PX = 25.0  # how far beyond the marker the surround is read along the line
MAX_BAND_RMS = 0.09      # an edge band's RMS residual over the marker's level, at most
MAX_SHIFT_PX = 8.0       # a vertex moved from the scans' by more: another optimum
CLIPPED_LEVEL = 250      # a pixel whose every channel reaches this is clipped
MAX_CLIPPED = 3          # clipped pixels in the quadrilateral's box, at most
SIGMA_SCALE = 3.0        # the fit's vertex sigma understates the error (correlated pixels)
SIGMA_FLOOR_PX = 0.15    # px
MAX_EVALUATIONS = 40     # the fit's budget (every fit taken converged within 26)
CHECK_SIGMA_PX = 1.2     # a found marker with a vertex this unsure (1 sigma, px) is checked
                         # (the extractor's max_vertex_sigma_px default; set apart from it)
CHECK_APART_PX = 2.0     # ... and refused where the fit puts a vertex further than this (px)
#: a found marker is checked too where over this share of the pixels just beyond an edge
#: pass the colour test (``profile.marker_beyond``: shaded ink beyond a shadow's boundary
#: taken for the edge; clean views' edges 0.5 at most)
CHECK_BEYOND_SHARE = 0.2
#: before fitting, the surround must darken across the interior's split line too: its
#: brightness ratio, read at these softnesses (px: ± 3.2 and ± 8 px off the line), at most
#: this in one of them (no taken fit was above 0.85; three in four fits not taken skipped)
PRECHECK_SOFTNESS_PX = (0.3, 10.0)
MAX_PRECHECK_RATIO = 0.85


#: refusals before any fit: the extractor's own refusal says enough
NO_QUADRILATERAL = "no quadrilateral to start from"
OUTSIDE_FRAME = "the quadrilateral is outside the frame"
NO_SHADOW_LINE = "no shadow's line across the marker"
UNTRIED = (NO_QUADRILATERAL, OUTSIDE_FRAME, NO_SHADOW_LINE)


@dataclass(frozen=True)
class ShadowFit:
    """A shadowed marker fitted whole: vertices (4, 2) px in the scans' order, their
    covariance (4, 2, 2) px², and the worst edge band's RMS residual as a distance (px:
    over the edge profile's steepest slope)."""

    vertices_px: np.ndarray
    cov_px2: np.ndarray
    residual_px: float


def _edges(v: np.ndarray) -> list[tuple[np.ndarray, float]]:
    """Each edge i (v[i] to v[i+1]) of the quadrilateral v (4, 2) px: its inward unit
    normal and offset (as ``quad_model.model`` computes them per fit evaluation)."""
    c = v.mean(0)
    out = []
    for i in range(4):
        a, b = v[i], v[(i + 1) % 4]
        t = b - a
        n = np.array([-t[1], t[0]]) / max(float(np.hypot(*t)), 1e-9)
        sign = 1.0 if (c - a) @ n >= 0 else -1.0
        out.append((sign * n, float(sign * n @ a)))
    return out


def model(p: np.ndarray, X: np.ndarray, Y: np.ndarray, jac: bool = False
          ) -> tuple[np.ndarray, np.ndarray | None]:
    """The score the 15 parameters p predict at the pixels X, Y (px), and its Jacobian
    (len(X), 15) if ``jac`` (``quad_model.model``, compiled)."""
    f, J = quad_model.model(np.ascontiguousarray(p, np.float64),
                            np.ascontiguousarray(X, np.float64),
                            np.ascontiguousarray(Y, np.float64), jac)
    return f, (J if jac else None)


def robust_lm(residual: Callable[[np.ndarray, bool], tuple[np.ndarray, np.ndarray | None]],
              p0: np.ndarray, f_scale: float, max_evaluations: int, ftol: float = 1e-6,
              xtol: float = 1e-8) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Minimise Σ f_scale² · 2 (√(1 + (r / f_scale)²) − 1) (the soft-L1 loss) over p by
    Levenberg-Marquardt on iteratively reweighted normal equations, Marquardt's scaling;
    ``residual(p, jac)`` gives r and, if ``jac``, its Jacobian. The solution, its residual
    and Jacobian; None if it did not converge within ``max_evaluations`` residuals."""

    def cost(r: np.ndarray) -> float:
        return float(np.sum(np.sqrt(1.0 + (r / f_scale) ** 2) - 1.0))

    p = p0.astype(float)
    r, J = residual(p, True)
    assert J is not None
    c, lam, evaluations = cost(r), 1e-3, 1
    while evaluations < max_evaluations:
        w = 1.0 / np.sqrt(1.0 + (r / f_scale) ** 2)
        JW = J * w[:, None]
        H, g = JW.T @ J, JW.T @ r
        D = np.diag(np.maximum(np.diag(H), 1e-12))
        while evaluations < max_evaluations:
            try:
                step = np.linalg.solve(H + lam * D, -g)
            except np.linalg.LinAlgError:
                return None
            trial = p + step
            rt, _ = residual(trial, False)
            evaluations += 1
            ct = cost(rt)
            if ct < c:
                break
            lam *= 4.0
        else:
            return None
        done = c - ct <= ftol * c or np.linalg.norm(step) <= xtol * (xtol + np.linalg.norm(p))
        p, c, lam = trial, ct, max(lam / 3.0, 1e-9)
        r, J = residual(p, True)
        assert J is not None
        if done:
            return p, r, J
    return None


def _score(box: np.ndarray, lut: np.ndarray, centre: tuple[int, int]) -> np.ndarray:
    """The chroma score of a BGR box: its linear colour projected on the unit direction of
    the 5 x 5 mean at ``centre`` (col, row in the box) away from grey."""
    lin = lut[box]
    cx, cy = centre
    q = lin[max(cy - 2, 0):cy + 3, max(cx - 2, 0):cx + 3].reshape(-1, 3).mean(0)
    return np.asarray(lin @ chroma_direction(q[0], q[1], q[2]))


def _split(S: np.ndarray, X: np.ndarray, Y: np.ndarray, v: np.ndarray
           ) -> tuple[float, float, float, float] | None:
    """The interior's (≥ 1 px inside) best two-level split by a line: its angle (rad, the
    lit side's normal), ρ (px), dark over lit level and lit level; None without enough
    interior."""
    inside = np.ones(S.shape, bool)
    for n, off in _edges(v):
        inside &= (n[0] * X + n[1] * Y - off) > 1.0
    s, x, y = S[inside], X[inside], Y[inside]
    N = s.size
    if N < MIN_INTERIOR_PX:
        return None
    best: tuple[float, float, float, float, float] | None = None
    i = np.arange(3, N - 3)
    for ang in np.radians(np.arange(0.0, 180.0, SPLIT_ANGLES_DEG)):
        pr = math.cos(ang) * x + math.sin(ang) * y
        o = np.argsort(pr)
        ss = s[o]
        cs, cs2 = np.cumsum(ss), np.cumsum(ss * ss)
        m1 = cs[i - 1] / i
        m2 = (cs[-1] - cs[i - 1]) / (N - i)
        sse = (cs2[i - 1] - i * m1 ** 2) + (cs2[-1] - cs2[i - 1] - (N - i) * m2 ** 2)
        j = int(np.argmin(sse))
        if best is None or sse[j] < best[0]:
            hi, lo = max(m1[j], m2[j]), min(m1[j], m2[j])
            rho = 0.5 * (pr[o][i[j] - 1] + pr[o][i[j]])
            up = m2[j] > m1[j]  # the lit side along +normal
            best = (float(sse[j]), ang if up else ang + math.pi, rho if up else -rho,
                    float(lo / hi) if hi > 0 else 1.0, float(hi))
    assert best is not None
    return best[1:]


def surround_ratio(image: np.ndarray, lut: np.ndarray, v: np.ndarray, ang: float, rho: float,
                   soft: float) -> tuple[float, int]:
    """The median brightness ratio (shaded / lit) across the shadow's line (angle, ρ) at
    ± (0.5 softness + 3) px, 1 px apart along it, at pixels at least 2 px outside the
    quadrilateral v; and the pairs' count."""
    n = np.array([math.cos(ang), math.sin(ang)])
    t = np.array([-n[1], n[0]])
    c = v.mean(0)
    foot = c - ((c @ n) - rho) * n
    half = float(np.abs((v - c) @ t).max()) + SURROUND_REACH_PX
    a = np.arange(-half, half, 1.0)
    delta = 0.5 * soft + 3.0
    pts = foot + a[:, None] * t
    lit, shaded = pts + delta * n, pts - delta * n
    H, W = image.shape[:2]
    edges = _edges(v)
    ok = np.ones(a.size, bool)
    for q in (lit, shaded):
        qi = np.rint(q).astype(int)
        ok &= (qi[:, 0] >= 0) & (qi[:, 0] < W) & (qi[:, 1] >= 0) & (qi[:, 1] < H)
        inside = np.ones(a.size, bool)
        for nn, off in edges:
            inside &= q @ nn - off >= -2.0
        ok &= ~inside
    if not ok.any():
        return math.nan, 0
    li = np.rint(lit[ok]).astype(int)
    si = np.rint(shaded[ok]).astype(int)
    y_lit = lut[image[li[:, 1], li[:, 0]]].sum(-1)
    y_shaded = lut[image[si[:, 1], si[:, 0]]].sum(-1)
    keep = y_lit > 3
    if not keep.any():
        return math.nan, 0
    return float(np.median(y_shaded[keep] / y_lit[keep])), int(keep.sum())


def fit(image: np.ndarray, v0: np.ndarray, lut: np.ndarray) -> ShadowFit | str:
    """The shadowed marker near the quadrilateral v0 (4, 2) px (the scans' refused one) in
    a BGR uint8 image, fitted whole; or why not (a string)."""
    H, W = image.shape[:2]
    if not np.isfinite(v0).all() or not np.abs(v0).sum() > 0:
        return NO_QUADRILATERAL
    x0, y0 = (int(z) for z in np.floor(v0.min(0) - MARGIN_PX))
    x1, y1 = (int(z) for z in np.ceil(v0.max(0) + MARGIN_PX))
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, W - 1), min(y1, H - 1)
    if x1 <= x0 or y1 <= y0:
        return OUTSIDE_FRAME
    if (x1 - x0 + 1) * (y1 - y0 + 1) > MAX_BOX_PX:
        return f"the marker's box is over {MAX_BOX_PX} px² (not fitted)"
    qx0, qy0 = max(int(np.floor(v0[:, 0].min())), 0), max(int(np.floor(v0[:, 1].min())), 0)
    qx1, qy1 = int(np.ceil(v0[:, 0].max())), int(np.ceil(v0[:, 1].max()))
    clipped = int((image[qy0:qy1 + 1, qx0:qx1 + 1].min(-1) >= CLIPPED_LEVEL).sum())
    if clipped > MAX_CLIPPED:
        return f"{clipped} clipped pixels on the marker (a highlight, not a shadow)"
    centre = v0.mean(0).astype(int)
    S = _score(image[y0:y1 + 1, x0:x1 + 1], lut, (int(centre[0]) - x0, int(centre[1]) - y0))
    Y, X = np.mgrid[y0:y1 + 1, x0:x1 + 1].astype(float)
    A0 = float(np.percentile(S, 95))
    split = _split(S, X, Y, v0)
    if split is None or split[2] >= MAX_SPLIT_RATIO:
        return NO_SHADOW_LINE
    ang, rho, k0, lit0 = split
    before = float(np.nanmin([surround_ratio(image, lut, v0, ang, rho, soft)[0]
                              for soft in PRECHECK_SOFTNESS_PX] + [math.inf]))
    if not before <= MAX_PRECHECK_RATIO:
        return (f"the surround does not darken across the marker's split line (brightness "
                f"ratio {before:.2f}): not a cast shadow")
    p0 = np.array([*v0.ravel(), 0.8, lit0, 0.0, k0, ang, rho, 0.3])
    dark = S[S < 0.2 * A0]
    f_scale = max(1.5 * float(np.median(np.abs(dark - np.median(dark)))) if dark.size else 0.0,
                  0.5)
    x, y, s = X.ravel(), Y.ravel(), S.ravel()

    def residual(p: np.ndarray, jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        f, J = model(p, x, y, jac)
        return f - s, J

    solved = robust_lm(residual, p0, f_scale, MAX_EVALUATIONS)
    if solved is None:
        return f"the fit did not converge in {MAX_EVALUATIONS} evaluations"
    p, r, J = solved
    v = p[:8].reshape(4, 2).copy()
    k, soft = float(p[11]), abs(p[14]) + 0.3
    if not MIN_K <= k <= MAX_K:
        return f"the shadow's fitted darkening {k:.2f} is outside [{MIN_K}, {MAX_K}]"
    shift = float(np.linalg.norm(v - v0, axis=1).max())
    if shift > MAX_SHIFT_PX:
        return f"the fit moved a vertex {shift:.1f} px from the scans' (another optimum)"
    ratio, pairs = surround_ratio(image, lut, v, float(p[12]), float(p[13]), soft)
    if not (pairs >= MIN_SURROUND_PAIRS and ratio <= MAX_SURROUND_RATIO
            and 0.5 * k <= ratio <= 2.0 * k):
        return (f"the surround does not show the shadow (brightness ratio {ratio:.2f} across "
                f"its line over {pairs} pixel pairs, for a darkening {k:.2f} on the marker)")
    worst, edge = band_rms(v, x, y, r, float(p[9]))
    if edge >= 0:
        return f"edge {edge} does not fit the shadowed marker (band RMS {worst:.3f} of its level)"
    cov = vertex_covariance(r, J, f_scale, SIGMA_SCALE, SIGMA_FLOOR_PX)
    if isinstance(cov, str):
        return cov
    if not np.isfinite(v).all():
        return "the fit's vertices are not finite"
    blur = abs(p[8]) + 0.3
    return ShadowFit(v, cov, worst * blur * math.sqrt(2.0 * math.pi))


def band_rms(v: np.ndarray, x: np.ndarray, y: np.ndarray, r: np.ndarray, level: float,
             limit: float = MAX_BAND_RMS, unseen: int = -1) -> tuple[float, int]:
    """The worst edge band's RMS residual r over the marker's ``level`` (the pixels x, y (px)
    within 2.5 px of an edge of the quadrilateral v (4, 2), 3 px clear of its ends), and the
    first edge over ``limit`` (-1: none); edge ``unseen`` is not tested."""
    worst = 0.0
    for i, (n, off) in enumerate(_edges(v)):
        if i == unseen:
            continue
        a, c = v[i], v[(i + 1) % 4]
        t = c - a
        L = float(np.hypot(*t))
        along = ((x - a[0]) * t[0] + (y - a[1]) * t[1]) / max(L, 1e-9)
        band = (np.abs(n[0] * x + n[1] * y - off) < 2.5) & (along > 3) & (L - along > 3)
        rms = float(np.sqrt(np.mean(r[band] ** 2))) / level if band.any() else math.inf
        if not rms <= limit:
            return rms, i
        worst = max(worst, rms)
    return worst, -1


def vertex_covariance(r: np.ndarray, J: np.ndarray, f_scale: float, scale: float,
                      floor_px: float, to_vertices: np.ndarray | None = None
                      ) -> np.ndarray | str:
    """The vertices' covariance (4, 2, 2) px² of a soft-L1 fit (residual r, Jacobian J, the
    first 8 columns the vertices, or the first k parameters mapped to them by
    ``to_vertices`` (8, k)): the loss's Gauss-Newton Hessian scaled by a robust residual
    variance, each vertex's larger variance times ``scale``² plus ``floor_px``², isotropic;
    or why not."""
    s2 = float(np.median(r ** 2)) / 0.455  # a robust residual variance
    # the loss's Gauss-Newton Hessian, as least_squares' modified Jacobian gives it
    Jm = J * ((1.0 + (r / f_scale) ** 2) ** -0.75)[:, None]
    try:
        C = np.linalg.inv(Jm.T @ Jm) * s2
    except np.linalg.LinAlgError:
        return "the fit's covariance is singular"
    if not np.isfinite(C).all():
        return "the fit's covariance is not finite"
    if to_vertices is not None:
        k = to_vertices.shape[1]
        C = to_vertices @ C[:k, :k] @ to_vertices.T
    var = np.maximum(np.diag(C)[:8], 0.0).reshape(4, 2).max(1)
    sigma2 = scale ** 2 * var + floor_px ** 2
    return np.asarray(sigma2[:, None, None] * np.eye(2))
