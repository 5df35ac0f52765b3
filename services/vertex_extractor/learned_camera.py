"""The camera learned from the marker's own detections, where no intrinsics were given.

Each detection of the rhombus (a planar shape of known proportions) is a homography of it;
with square pixels and no skew, two such views of different tilts fix the focal length and
the principal point (Zhang's constraints on the image of the absolute conic, with ω's skew
term zero and its two diagonal terms equal). Over many detections the camera comes out as
well as the marker's vertices tell it: from 100 clean webcam renders' detections of 28
seeds, the paper's camera (fx 757, fy 754, principal point (390, 261) px) came out at
750-770 px and 4-18 px off (docs/measured.md "The camera learned from the marker").

``CameraLearner`` keeps the scans' confident detections of distinct views and, every
``SOLVE_EVERY`` new views (less often once a camera is offered), solves the older and the
newer half of them apart, a few steps at each detection (``solve``: the closed form, then
every pose and the three intrinsics by Levenberg-Marquardt on the vertices' whitened errors,
the poses eliminated);
it offers their combination (``camera``) where the halves agree within their standard
errors or within the band used (``AGREE_CHI2``, ``AGREE_PP_W``: one camera, not a blend of
two after a zoom or a swap). What for: a marker under a highlight whose hidden edge depends
on the camera (``highlight.fit``) is fitted under the learned camera's focal length ±
``BAND`` and its principal point ± ``PP_SPREAD_W`` x the width instead of assumed ones over
the range webcams have. Markers under ``MIN_MARKER_PX`` tall are not learned from, and after
``QUICK_RETRIES`` failed solves in a row the next waits twice as long: views that fit no
camera (small markers, a rolling shutter's) had kept a solve under way (about 1.4 ms a
step then, 0.85 ms now that the Jacobian's 18 evaluations are one) on most frames. Pure
numpy and OpenCV; no bus.
"""

from __future__ import annotations

import math
from collections.abc import Generator
from dataclasses import dataclass
from typing import TypeVar

import cv2
import numpy as np

from services.core.camera import CameraModel

T = TypeVar("T")

MIN_VIEWS = 40           # distinct views before the first solve (two halves of 20)
SOLVE_EVERY = 20         # new views between solves; doubled after each solve offered, up to
MAX_SOLVE_EVERY = 80     # this (a camera changed is noticed within as many new views)
QUICK_RETRIES = 2        # failed solves in a row retried after SOLVE_EVERY; then backing off
MIN_SOLVED = 12          # a solve's views, at least, after those far off are left out
MAX_VIEWS = 120          # the newest views kept
STEPS_PER_ADD = 3        # a solve under way is worked on this many steps a new view kept
                         # (up to 3 ms: a solve of both halves over 10-50 new views)
MIN_MARKER_PX = 40.0     # a detection whose top-to-bottom diagonal is shorter (px) is not
                         # learned from: 25-40 px markers' views fit no camera (chi² 4-5 per
                         # degree of freedom), and kept a failing solve under way on most frames
NEW_VIEW_PX = 5.0        # a view is new when a vertex's coordinate is this far (px) from its
                         # place in every view kept
MAX_SIGMA_PX = 0.5       # a detection with a vertex's variance (its covariance's trace) over
                         # this squared (px²) is not learned from
MAX_SE_F = 0.02          # a solve's focal length's standard error, at most this share
MAX_SE_PP_W = 0.03       # ... its principal point's, at most this share of the width
MAX_CHI2 = 4.0           # the inliers' whitened squared error per degree of freedom, at most
OUTLIER_CHI2 = 72.0      # a view whose 8 whitened errors square to more (their RMS over 3)
OUTLIER_PASSES = 2       # is left out and the rest solved again, at most this many times
HALF_SLACK = 2.0         # each half's standard errors within this x a solve's limits
AGREE_CHI2 = 16.3        # the halves' solves agree: their differences' chi² (3 degrees of
                         # freedom, by their standard errors) at most this (99.9 %), or ...
AGREE_PP_W = 0.03        # ... their focal lengths within BAND and principal points within
                         # this share of the width (their standard errors understate the
                         # renders' halves' scatter: 757 and 771 px apart at 0.4 % each)
PP_SPREAD_W = 0.02       # ... and its principal point moved this share of the width each way
                         # (the renders' learned principal points were 4-18 px off, at
                         # standard errors of 1-3 px: a pose on three vertices followed it)
BAND = 0.03              # the learned focal length's band the highlight's pose is fitted over
HUBER = 3.0              # whitened errors beyond this weigh as Huber's
MAX_ITERATIONS = 50       # Levenberg-Marquardt's steps, at most
FOCAL_RANGE_W = (0.3, 3.0)  # a plausible focal length (x the width)
PP_RANGE = 0.3           # a plausible principal point: this share of the size from the centre


@dataclass(frozen=True)
class Solved:
    """A solve: focal length f and principal point (cx, cy) px, their standard errors px,
    the views used and the inliers' whitened squared error per degree of freedom."""

    f: float
    cx: float
    cy: float
    se: tuple[float, float, float]
    views: int
    chi2: float

    def camera(self, width: int, height: int, f: float | None = None) -> CameraModel:
        """The camera (square pixels, no skew or distortion), at focal length ``f`` px if
        given."""
        return CameraModel.pinhole(self.f if f is None else f, self.cx, self.cy, width, height)


def _rotations(r: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) of rotation vectors r (n, 3) rad."""
    theta = np.linalg.norm(r, axis=1)
    k = r / np.maximum(theta, 1e-12)[:, None]
    K = np.zeros((r.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def _closed_form(model_xy: np.ndarray, views: np.ndarray) -> tuple[float, float, float] | None:
    """Zhang's closed form with zero skew and square pixels: (f, cx, cy) px from the views
    (n, 4, 2) px of the planar points ``model_xy`` (4, 2) m; None where it has no solution."""
    rows = []
    for v in views:
        H, _ = cv2.findHomography(model_xy, v)
        if H is None:
            continue
        H = H / np.linalg.norm(H[:, :2])

        def term(i: int, j: int, H: np.ndarray = H) -> np.ndarray:
            """Zhang's v_ij with B12 = 0 and B22 = B11: (B11, B13, B23, B33). (Not
            ``calibration.zhang``'s: a service imports no other service's modules.)"""
            a, b = H[:, i], H[:, j]
            return np.array([a[0] * b[0] + a[1] * b[1], a[0] * b[2] + a[2] * b[0],
                             a[1] * b[2] + a[2] * b[1], a[2] * b[2]])
        rows += [term(0, 1), term(0, 0) - term(1, 1)]
    if len(rows) < 4:
        return None
    b = np.linalg.svd(np.array(rows))[2][-1]
    if abs(b[0]) < 1e-15:
        return None
    cx, cy = -b[1] / b[0], -b[2] / b[0]
    f2 = b[3] / b[0] - cx * cx - cy * cy
    return (math.sqrt(f2), cx, cy) if f2 > 0 else None


def solve(model_m: np.ndarray, views_px: np.ndarray, covs_px2: np.ndarray, width: int,
          height: int) -> Solved | str:
    """The camera (square pixels, no skew or distortion) that best explains the views
    (n, 4, 2) px of the planar rhombus ``model_m`` (4, 3) m (z = 0), each vertex weighted by
    its covariance (n, 4, 2, 2) px²; or why not (``solving`` run to its end)."""
    return _run(solving(model_m, views_px, covs_px2, width, height))


def _run(work: Generator[None, None, T]) -> T:
    """A generator's return value, run to its end."""
    while True:
        try:
            next(work)
        except StopIteration as done:
            return done.value  # type: ignore[no-any-return]


def solving(model_m: np.ndarray, views_px: np.ndarray, covs_px2: np.ndarray, width: int,
            height: int) -> Generator[None, None, Solved | str]:
    """``solve`` one step at a time (it yields after the start and after each
    Levenberg-Marquardt step: a frame pays a few steps, not a whole solve). Started from the
    closed form (else a focal length of the width, the principal point at the centre), with
    each view's pose from IPPE; views far off (``OUTLIER_CHI2``) are left out and the rest
    solved again (``OUTLIER_PASSES``)."""
    n = views_px.shape[0]
    if n < MIN_SOLVED:
        return f"{n} views (at least {MIN_SOLVED})"
    M = np.asarray(model_m, float)
    start = _closed_form(M[:, :2], views_px)
    lo, hi = (r * width for r in FOCAL_RANGE_W)
    if start is None or not lo <= start[0] <= hi:
        start = (float(width), 0.5 * (width - 1), 0.5 * (height - 1))
    try:  # (each vertex's error whitened: L e, with L^T L the covariance's inverse)
        L = np.linalg.cholesky(np.linalg.inv(covs_px2 + 1e-6 * np.eye(2))).transpose(0, 1, 3, 2)
    except np.linalg.LinAlgError:
        return "a view's covariance is not positive definite"
    keep = np.ones(n, bool)
    for attempt in range(OUTLIER_PASSES + 1):
        got = yield from _refine(M, views_px[keep], L[keep], start)
        if isinstance(got, str):
            return got
        x, view_chi2, se = got
        outliers = view_chi2 > OUTLIER_CHI2
        if not outliers.any():
            break
        if attempt == OUTLIER_PASSES:
            return f"views still far off the best camera after {OUTLIER_PASSES} passes"
        keep[np.flatnonzero(keep)[outliers]] = False
        if keep.sum() < MIN_SOLVED:
            return f"{int((~keep).sum())} of {n} views far off the best camera"
        start = (x[0], x[1], x[2])
    m = view_chi2.size
    chi2 = float(view_chi2.sum() / max(2 * m - 3, 1))
    return Solved(float(x[0]), float(x[1]), float(x[2]), se, m, chi2)


def _refine(M: np.ndarray, views: np.ndarray, L: np.ndarray,
            start: tuple[float, float, float]
            ) -> Generator[None, None,
                           tuple[np.ndarray, np.ndarray, tuple[float, float, float]] | str]:
    """Levenberg-Marquardt over (f, cx, cy) and every view's pose (rotation vector rad,
    translation m), the poses eliminated at each step (the Schur complement: a 3 x 3 system
    for the intrinsics, a 6 x 6 one per view), each whitened error weighted as Huber's at
    ``HUBER`` sigma; returns (f, cx, cy), each view's whitened squared error and the
    intrinsics' standard errors (px). Yields after the poses' start and after each step."""
    n = views.shape[0]
    K0 = np.array([[start[0], 0.0, start[1]], [0.0, start[0], start[2]], [0.0, 0.0, 1.0]])
    P = np.empty((n, 6))
    for i, v in enumerate(views):
        ok, r, t = cv2.solvePnP(M, v.reshape(-1, 1, 2), K0, None, flags=cv2.SOLVEPNP_IPPE)
        if not ok:
            return "a view has no pose"
        P[i] = np.r_[r.ravel(), t.ravel()]
    yield  # (the poses started: 30 µs a view)
    c = np.array(start, float)
    mx, my = M[:, 0], M[:, 1]

    def whitened_many(c: np.ndarray, P: np.ndarray) -> np.ndarray:  # (m, n, 8)
        """The whitened errors of m cameras c (m, 3) and pose sets P (m, n, 6) at once."""
        m = c.shape[0]
        R = _rotations(P[..., :3].reshape(-1, 3)).reshape(m, n, 3, 3)
        X = R[:, :, None, :, 0] * mx[None, None, :, None] \
            + R[:, :, None, :, 1] * my[None, None, :, None] \
            + P[:, :, None, 3:]  # (m, n, 4, 3) m, the camera's frame
        z = np.maximum(X[..., 2], 1e-6)
        f, cx, cy = (c[:, k, None, None] for k in range(3))
        e = np.stack([f * X[..., 0] / z + cx, f * X[..., 1] / z + cy], -1) - views
        return np.einsum("nkij,mnkj->mnki", L, e).reshape(m, n, 8)

    def whitened(c: np.ndarray, P: np.ndarray) -> np.ndarray:  # (n, 8)
        return whitened_many(c[None], P[None])[0]

    def cost(r: np.ndarray) -> float:
        a = np.abs(r)
        return float(np.where(a <= HUBER, 0.5 * a * a, HUBER * (a - 0.5 * HUBER)).sum())

    h_c = 1e-4 * max(start[0], 1.0)
    h_p = np.array([1e-6, 1e-6, 1e-6, 1e-7, 1e-7, 1e-7])
    r = whitened(c, P)
    lam = 1e-3
    steps = np.r_[np.full(3, h_c), h_p]  # the central differences' steps, (f, cx, cy) then
    D = np.vstack([np.diag(steps), -np.diag(steps)])  # each view's pose: (18, 9)
    for _ in range(MAX_ITERATIONS):
        w18 = whitened_many(c + D[:, :3], P[None] + D[:, None, 3:])  # (18, n, 8), one call
        J = ((w18[:9] - w18[9:]) / (2.0 * steps)[:, None, None]).transpose(1, 2, 0)
        Jc, Jp = J[:, :, :3], J[:, :, 3:]  # (n, 8, 3) and (n, 8, 6)
        w = np.minimum(1.0, HUBER / np.maximum(np.abs(r), 1e-12))  # (n, 8) IRLS weights
        App = np.einsum("nki,nk,nkj->nij", Jp, w, Jp)
        Apc = np.einsum("nki,nk,nkj->nij", Jp, w, Jc)
        Acc = np.einsum("nki,nk,nkj->ij", Jc, w, Jc)
        gp = np.einsum("nki,nk,nk->ni", Jp, w, r)
        gc = np.einsum("nki,nk,nk->i", Jc, w, r)
        before = cost(r)
        while True:
            Dp = App + lam * np.einsum("nii->ni", App)[:, :, None] * np.eye(6)
            try:
                X = np.linalg.solve(Dp, np.concatenate([Apc, gp[:, :, None]], 2))
            except np.linalg.LinAlgError:
                return "a view's pose is degenerate"
            S = Acc + lam * np.diag(np.diag(Acc)) - np.einsum("nji,njk->ik", Apc, X[:, :, :3])
            rhs = gc - np.einsum("nji,nj->i", Apc, X[:, :, 3])
            try:
                dc = -np.linalg.solve(S, rhs)
            except np.linalg.LinAlgError:
                return "the views do not fix the camera (all seen face on?)"
            dP = -X[:, :, 3] - np.einsum("nij,j->ni", X[:, :, :3], dc)
            r_new = whitened(c + dc, P + dP)
            if np.isfinite(r_new).all() and cost(r_new) < before:
                c, P, r = c + dc, P + dP, r_new
                lam = max(lam / 3.0, 1e-9)
                break
            lam *= 10.0
            if lam > 1e8:
                break
        if lam > 1e8 or (before - cost(r)) < 1e-6 * max(before, 1.0):
            break
        yield
    # the intrinsics' covariance (unit weights): the Schur complement of the poses' blocks
    App = np.einsum("nki,nkj->nij", Jp, Jp)
    Apc = np.einsum("nki,nkj->nij", Jp, Jc)
    try:
        S = np.einsum("nki,nkj->ij", Jc, Jc) - np.einsum(
            "nji,njk->ik", Apc, np.linalg.solve(App, Apc))
        view_chi2 = (r ** 2).sum(1)
        cov = np.linalg.inv(S) * max(float(view_chi2.sum()) / max(2 * n - 3, 1), 1.0)
    except np.linalg.LinAlgError:
        return "the views do not fix the camera (all seen face on?)"
    if not (np.isfinite(cov).all() and (np.diag(cov) > 0.0).all()):
        return "the views do not fix the camera (all seen face on?)"
    se = np.sqrt(np.diag(cov))
    return c, view_chi2, (float(se[0]), float(se[1]), float(se[2]))


def judge(s: Solved, width: int, height: int, slack: float = 1.0) -> str:
    """Why a solve is not a usable camera, or '' (its standard errors' limits x ``slack``)."""
    lo, hi = (r * width for r in FOCAL_RANGE_W)
    if not lo <= s.f <= hi:
        return f"its focal length {s.f:.0f} px is outside {lo:.0f}-{hi:.0f} px"
    if abs(s.cx - 0.5 * (width - 1)) > PP_RANGE * width or \
            abs(s.cy - 0.5 * (height - 1)) > PP_RANGE * height:
        return f"its principal point ({s.cx:.0f}, {s.cy:.0f}) px is far off the centre"
    if s.se[0] > slack * MAX_SE_F * s.f:
        return f"its focal length is uncertain (± {s.se[0]:.0f} px)"
    if max(s.se[1], s.se[2]) > slack * MAX_SE_PP_W * width:
        return f"its principal point is uncertain (± {max(s.se[1], s.se[2]):.0f} px)"
    if s.chi2 > MAX_CHI2:
        return f"the views fit it poorly (chi² {s.chi2:.1f} per degree of freedom)"
    return ""


def _disagreement(a: Solved, b: Solved) -> float:
    """The chi² of two solves' differences in (f, cx, cy), by their standard errors."""
    return sum((x - y) ** 2 / max(sa * sa + sb * sb, 1e-12)
               for x, y, sa, sb in zip((a.f, a.cx, a.cy), (b.f, b.cx, b.cy), a.se, b.se,
                                       strict=True))


def combined(a: Solved, b: Solved) -> Solved:
    """Two solves of disjoint views as one: each intrinsic their inverse-variance weighted
    mean, its standard error combined; the views summed, the chi² their views' mean."""
    est, se = [], []
    for x, y, sa, sb in zip((a.f, a.cx, a.cy), (b.f, b.cx, b.cy), a.se, b.se, strict=True):
        wa, wb = 1.0 / max(sa * sa, 1e-12), 1.0 / max(sb * sb, 1e-12)
        est.append((wa * x + wb * y) / (wa + wb))
        se.append(1.0 / math.sqrt(wa + wb))
    n = a.views + b.views
    return Solved(est[0], est[1], est[2], (se[0], se[1], se[2]), n,
                  (a.chi2 * a.views + b.chi2 * b.views) / n)


class CameraLearner:
    """The camera of ``width`` x ``height`` px frames, learned from detections of the
    rhombus ``model_m`` (4, 3) m (``add``); ``camera()`` once the halves of a solve agree.
    A solve due is worked on ``STEPS_PER_ADD`` steps at each ``add`` of a new view kept (its
    older half, then its newer, then judged): no frame pays more than a few milliseconds for
    it, and a tracked marker standing still nothing."""

    def __init__(self, model_m: np.ndarray, width: int, height: int) -> None:
        self.model_m = np.asarray(model_m, float)
        self.width, self.height = width, height
        # the views kept, a ring (the oldest overwritten): vertices px and covariances px²
        self._vertices = np.empty((MAX_VIEWS, 4, 2))
        self._covs = np.empty((MAX_VIEWS, 4, 2, 2))
        self._kept = 0  # views kept, at most MAX_VIEWS
        self._next = 0  # the ring's slot for the next view
        #: the ring's slot of the view kept last, or of the one kept that a later confident
        #: view was found near: a view near it is no new view without a look through the
        #: views kept (a tracked marker standing still, or one found again where it was)
        self._seen: int | None = None
        self._new = 0
        self._every = SOLVE_EVERY
        self._failed = 0  # solves failed in a row
        self._work: Generator[None, None, None] | None = None  # the solve under way
        #: the newest solve, or why it is not a usable camera
        self.last: Solved | str = f"fewer than {MIN_VIEWS} distinct views of the marker"
        self._agreed: Solved | None = None

    def add(self, vertices_px: np.ndarray, cov_px2: np.ndarray) -> None:
        """A detection's vertices (4, 2) px and covariance (4, 2, 2) px²: kept if confident
        (every vertex's covariance positive definite, its trace at most ``MAX_SIGMA_PX``²)
        and a new view (a vertex's coordinate at least ``NEW_VIEW_PX`` from its place in every
        view kept); then a solve under way is worked on, or one begun when due (only a view
        kept pays for the solve: a tracked marker standing still pays nothing, nor one found
        again where it was last seen)."""
        seen = self._seen  # (a tracked marker: mostly where it was)
        if seen is not None and float(np.abs(self._vertices[seen] - vertices_px).max()
                                      ) < NEW_VIEW_PX:
            return
        if float(np.hypot(*(vertices_px[3] - vertices_px[1]))) < MIN_MARKER_PX:
            return  # (a small marker: too little perspective to tell a focal length)
        if not (np.isfinite(vertices_px).all() and np.isfinite(cov_px2).all()) or \
                float((cov_px2[:, 0, 0] + cov_px2[:, 1, 1]).max()) > MAX_SIGMA_PX ** 2 or \
                not ((cov_px2[:, 0, 0] > 0.0) & (cov_px2[:, 0, 0] * cov_px2[:, 1, 1]
                                               > cov_px2[:, 0, 1] * cov_px2[:, 1, 0])).all():
            return  # (not numbers, too uncertain, or no covariance)
        if self._kept:
            nearest, apart_px = self._nearest_kept(vertices_px)
            if apart_px < NEW_VIEW_PX:
                self._seen = nearest
                return
        self._seen = self._next
        self._vertices[self._next] = vertices_px
        self._covs[self._next] = cov_px2
        self._next = (self._next + 1) % MAX_VIEWS
        self._kept = min(self._kept + 1, MAX_VIEWS)
        self._new += 1
        if self._work is not None:
            for _ in range(STEPS_PER_ADD):
                try:
                    next(self._work)
                except StopIteration:
                    self._work = None
                    break
                except Exception as err:  # (OpenCV or numpy on views it cannot take)
                    self._work, self._agreed = None, None
                    self.last = f"the solve failed: {err}"
                    break
        if self._work is None and self._kept >= MIN_VIEWS and self._new >= self._every:
            self._new = 0
            order = np.roll(np.arange(self._kept), -self._next if self._kept == MAX_VIEWS
                            else 0)  # (oldest first)
            self._work = self._solving(self._vertices[order], self._covs[order])

    def _nearest_kept(self, vertices_px: np.ndarray) -> tuple[int, float]:
        """The ring's slot of the view kept nearest the view ``vertices_px`` (4, 2) px, and how
        far it is (px: the largest of their vertices' coordinates' differences)."""
        apart = np.abs(self._vertices[:self._kept] - vertices_px).max(axis=(1, 2))
        nearest = int(np.argmin(apart))
        return nearest, float(apart[nearest])

    def _solving(self, views: np.ndarray, covs: np.ndarray) -> Generator[None, None, None]:
        """The older and newer halves of ``views`` (with ``covs``) solved apart, step by step,
        and judged: the camera is offered where their combination is a usable camera and
        they agree (``AGREE_CHI2``, else within ``BAND`` and ``AGREE_PP_W``: not a blend of
        two cameras, after a zoom or a swap); else none."""
        k = len(views) // 2
        older = yield from solving(self.model_m, views[:k], covs[:k], self.width, self.height)
        newer = yield from solving(self.model_m, views[k:], covs[k:], self.width, self.height)
        self._agreed = None
        # (a failed solve: the next one SOLVE_EVERY new views on, but after QUICK_RETRIES
        # failures in a row twice as many as this one's, up to MAX_SOLVE_EVERY: views that fit
        # no pinhole camera, a rolling shutter's, kept a solve under way on most frames)
        every, self._failed = self._every, self._failed + 1
        self._every = SOLVE_EVERY if self._failed <= QUICK_RETRIES else min(
            2 * every, MAX_SOLVE_EVERY)
        if isinstance(older, str) or isinstance(newer, str):
            self.last = f"a half of the views: {older if isinstance(older, str) else newer}"
            return
        for part in (older, newer):  # (a half that tells little agrees with anything)
            if why := judge(part, self.width, self.height, HALF_SLACK):
                self.last = f"a half of the views: {why}"
                return
        whole = combined(older, newer)
        if why := judge(whole, self.width, self.height):
            self.last = why
        elif _disagreement(older, newer) > AGREE_CHI2 and (
                abs(older.f - newer.f) > BAND * whole.f or math.hypot(
                    older.cx - newer.cx, older.cy - newer.cy) > AGREE_PP_W * self.width):
            self.last = (f"the older and newer views disagree: focal length {older.f:.0f} "
                         f"and {newer.f:.0f} px, principal point ({older.cx:.0f}, "
                         f"{older.cy:.0f}) and ({newer.cx:.0f}, {newer.cy:.0f}) px")
        else:
            self.last = self._agreed = whole
            self._every, self._failed = min(2 * every, MAX_SOLVE_EVERY), 0

    def camera(self) -> Solved | None:
        """The newest solve, if it is a usable camera whose halves agree."""
        return self._agreed

    def cameras(self, pp_spread: bool = False) -> list[CameraModel]:
        """The learned camera at the ends of its focal length's band (``BAND``), and with
        ``pp_spread`` at its focal length with the principal point moved ``PP_SPREAD_W`` x
        the width right, left, down and up (the highlight's pose fits); none until learned."""
        s = self._agreed
        if s is None:
            return []
        cams = [s.camera(self.width, self.height, s.f * (1.0 + k * BAND)) for k in (-1, 1)]
        if pp_spread:
            d = PP_SPREAD_W * self.width
            cams += [CameraModel.pinhole(s.f, s.cx + dx, s.cy + dy, self.width, self.height)
                     for dx, dy in ((d, 0.0), (-d, 0.0), (0.0, d), (0.0, -d))]
        return cams
