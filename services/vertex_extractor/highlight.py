"""The marker under a clipped highlight (a glossy print), fitted whole to the pixels that did
not clip: the extractor's last resort for a marker its scans refuse there (issue 21;
docs/measured.md "A model of the marker under a highlight").

White light added to the marker leaves its chroma score (``colour.py``'s vector: linear
colour along the marker's chroma direction, orthogonal to grey) unchanged, until a channel
clips. So the score in the marker's box, with every pixel within ``MASK_PX`` of a clipped
one (some channel at ``CLIPPED_LEVEL`` or more) left out (and, in a box over
``shadow.MAX_BOX_PX``, a near marker's, all but every second row and column; such a marker
is not checked, below), is fitted as the unshadowed model of ``shadow.py``:

    score(x, y) = b + A · Π_edges Φ(d_i / σ)

(11 parameters, ``shadow.robust_lm``). The start is the convex hull of the seed's blob (its
marker-coloured pixels, the pieces a highlight splits it into joined across clipped ones
within ``JOIN_PX``, and those clipped pixels), cut down to its four extreme points (the
hull's diameter and the points farthest from it on each side). It is tried only where
white lies on the blob or within ``WHITE_NEAR_PX`` of it: a highlight's core, not an
over-exposed ink. As the last resort for a marker every scan refused, white is every channel
at ``GLOW_LEVEL`` or more (a glow that clips the ink's red but leaves the wall beside it
unclipped is a highlight too), and the blob's pieces are joined across the highlight's halo
(``halo_mask``: the marker's colour plus white light, which fails the colour test; a
washed-out ring wider than ``JOIN_PX`` kept a clipped core from the blob) as well as across
clipped pixels; the fit's marker pixels are the colour test's as before. A blob that
reaches the side of the ``WINDOW_PX`` window around the seed inside the image is looked for
again in a window grown past it on that side (up to ``MAX_WINDOW_PX`` a side), and refused
where it would outgrow that: fitted to the part inside, a marker taller than the window came
out with a vertex 5.7 px off. As a check of a found marker, clipped white (``CLIPPED_LEVEL``) it is,
without the halo.

A free fit is taken only if every edge is seen over at least ``MIN_SUPPORT`` of its length
(an edge under the highlight from end to end is not measured), every edge's band fits within
``MAX_BAND_RMS`` of the marker's level, the edges' fitted blur is at most ``MAX_BLUR_PX``
(more: not a clean step), no vertex's reported sigma is over ``MAX_SIGMA_PX`` (a vertex
extrapolated far under the highlight), and the fit converged; then the tests any detection
passes. Its vertices' reported sigma: ``SIGMA_SCALE`` times the fit's, with a floor
``SIGMA_FLOOR_PX`` (isotropic, px): the vertices a highlight hides are extrapolated from the
visible parts of their edges, and the pixels next to the clipped ones are not quite clean
(demosaicing, JPEG's chroma).

With the camera's intrinsics, a free fit refused for an edge under the highlight or for a
vertex's uncertainty is fitted again as the deployment's rhombus seen by the camera: its
pose (6 parameters) instead of the vertices, whatever the other edges show, started from the
poses that put it on the three edges seen best (``recover.p3l``) and from IPPE, the best
``POSE_STARTS`` fitted. Where another pose fits within ``POSE_TIE`` of the best cost with a
vertex more than ``POSE_APART_PX`` away, the edges seen do not tell (refused); the edges'
bands (but a hidden one's) and the blur are tested as above, and a vertex's sigma must be at
most ``MAX_POSE_SIGMA_PX``. The known shape and camera fix what the highlight hides: with
intrinsics the highlight's views are found on 97-98 % (92-93 % with the pose for one hidden
edge only, beside three seen over 30 % of their length), about 1 % of the pose's detections
over 2 px off (docs/measured.md).

Without intrinsics, a camera is assumed: square pixels, no distortion. Only the focal length
and the principal point are then unknown, and the edges seen leave them free: the pose is
fitted as above under two cameras and taken where both are taken, their vertices' mean, each
covariance the larger plus their distance from the mean squared, within
``MAX_POSE_SIGMA_PX``, another pose within ``POSE_TIE_ASSUMED`` of the best refusing (the
assumed camera's error moves the poses' costs). The two cameras: once the extractor has
learned the camera from the marker (``learned_camera.py``), its focal length ± 3 % and its
principal point (found on 96-97 % of the highlight's views, at most 0.3 % wrong); before
that, the focal lengths ``ASSUMED_FOCAL_W`` (times the frame's width) with the principal
point at the frame's centre (the frame must be the camera's whole image, not a crop): 90-93 %
instead of 85-88 %, at most 0.3 % wrong. Under these, a pose must see three edges over
``MIN_SECOND_SUPPORT`` of their length: the principal point assumed is not varied, and a pose on two
edges and the vertices between them followed it (seed 2024, view 213: two vertices 14-15 px
off at a reported 0.3 px; 1 of 900 views lost, none wrong).

The same fit checks a marker the scans *found* with clipped white within ``CHECK_NEAR_PX``
of a vertex (``start_px``: started from their vertices, with ``CHECK_START_BLUR_PX``; the
extractor's ``_checked_under_highlight`` judges it against ``CHECK_APART_PX`` and
``CHECK_MAX_SIGMA_PX``): the halo beside a clipped core bends the scans' edge points.

Tuned on seeds 2024, 7 and 11 (``MAX_SIGMA_PX`` and the check on seeds 200-209); held out on
seeds 31-35 and other photographs. numpy and OpenCV, the model compiled (``quad_model.py``):
20 ms a fit at the median, 62 ms at the 95th percentile, 0.16 s at most (a fit may take up
to ``MAX_EVALUATIONS``: a start far off crawls in); with intrinsics, the free fit and the
pose's together 65 ms, 0.21 s and 0.84 s (without intrinsics, the two assumed cameras' poses
98 ms more at the median); a check 21 ms, 43 ms and 75 ms. Only views
every other route refused, with clipped white on the blob, and found markers with clipped
white near a vertex pay it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from services.core.camera import CameraModel, undistort_px
from services.pose_estimator.p4p import OK, ippe4
from services.vertex_extractor import recover, shadow
from services.vertex_extractor.colour import (
    HALO_MIN_CHROMA,
    chroma_direction,
    grid_mask,
    lit_marker_mask,
)
from services.vertex_extractor.profile import EDGE_NAMES

CLIPPED_LEVEL = shadow.CLIPPED_LEVEL  # a pixel with a channel at or above this has clipped
WINDOW_PX = 160          # the blob is looked for within this of the seed (px)
MAX_WINDOW_PX = 800      # ... and again, wider, where the blob reaches its side, up to this
JOIN_PX = 22             # the blob's pieces joined across clipped pixels this near (px)
WHITE_NEAR_PX = 20       # clipped white this near the blob (px) makes it a highlight's
GLOW_LEVEL = 230         # ... as a last resort, white (every channel) at least this (sRGB)
MASK_PX = 2              # pixels this near a clipped one are left out of the fit (px)
MARGIN_PX = 14           # the fitted box: the start's plus this (px)
MIN_MARKER_PX = 20       # the blob's unclipped marker pixels, at least
MIN_SUPPORT = 0.2        # every edge's share seen (not masked), at least (but as a pose)
MIN_SECOND_SUPPORT = 0.1  # under assumed cameras, a pose's second least seen edge, at least
POSE_STARTS = 3          # the poses fitted, from the starts that fit best
POSE_TIE = 0.005         # another pose whose cost is within this share of the best ...
POSE_TIE_ASSUMED = 0.01  # ... (a camera assumed or learned: its error moves the poses' costs;
                         # the true camera's tie 0.1 % apart was 0.9 % under the learned one)
POSE_APART_PX = 1.0      # ... with a vertex further than this from the best's: ambiguous
MAX_BAND_RMS = 0.1       # an edge band's RMS residual over the marker's level, at most
MAX_BLUR_PX = 2.0        # the edges' fitted blur (Gaussian sigma, px), at most
SIGMA_SCALE = 5.0        # the fit's vertex sigma understates the error (see the docstring)
SIGMA_FLOOR_PX = 0.15    # px
MAX_SIGMA_PX = 0.5       # a vertex more uncertain (1 sigma, px) refuses the free fit: more
                         # were wrong there (seeds 200-209: 7 of 348 fits up to 1.2 px)
MAX_POSE_SIGMA_PX = 0.8  # ... a pose's (with intrinsics: 3 of the 9 wrong of 628 over it;
                         # without, the assumed cameras' too, their spread included)
START_BLUR_PX = 2.5      # the blur the fit starts from: wide, so that edges far off pull
CHECK_START_BLUR_PX = 1.5  # ... from the scans' vertices (a check): they are near
CHECK_NEAR_PX = 25       # a found marker with clipped white this near a vertex is checked (px)
CHECK_APART_PX = 1.0     # the check's fit moving a vertex further than this (px) overrules
CHECK_MAX_SIGMA_PX = 0.7  # ... the scans: its vertices taken if none is more uncertain
                         # (reported, 1 sigma, px) than this; the marker refused otherwise
CHECK_APART_SHARE = 0.5  # a taken check's vertex sigma grows by this share of its move (px):
                         # the fit's alone had 19 of 137 more than 3 sigmas off, this 5
MAX_EVALUATIONS = 80     # the fit's budget
#: without intrinsics, the pose is fitted under cameras with these focal lengths (x the
#: image's width: horizontal fields of view of 90 and 39 deg, most webcams'), the principal
#: point at the centre; taken where they agree (their spread in the uncertainty)
ASSUMED_FOCAL_W = (0.5, 1.4)

#: not tried: the extractor's own refusal says enough
NO_HIGHLIGHT = "no clipped white (or glow) on the marker's blob"
NO_BLOB = "no marker-coloured blob at the seed"
UNTRIED = (NO_HIGHLIGHT, NO_BLOB)


@dataclass(frozen=True)
class HighlightFit:
    """A marker under a highlight fitted whole: vertices (4, 2) px (left, top, right,
    bottom), their covariance (4, 2, 2) px², and the worst edge band's RMS residual as a
    distance (px: over the edge profile's steepest slope)."""

    vertices_px: np.ndarray
    cov_px2: np.ndarray
    residual_px: float


def clockwise_from_left(v: np.ndarray) -> np.ndarray:
    """The indices that order the convex quadrilateral v (4, 2) px clockwise on screen (y
    down) from its leftmost vertex: left, top, right, bottom."""
    c = v.mean(0)
    order = np.argsort(np.arctan2(v[:, 1] - c[1], v[:, 0] - c[0]))
    first = int(np.argmin(v[order, 0]))
    return np.roll(order, -first)


def extreme_points(points: np.ndarray) -> np.ndarray | None:
    """Four points of the convex hull of ``points`` (n, 2) px: its diameter's ends and the
    points farthest from the diameter on each side, left, top, right, bottom; None if the
    hull is degenerate."""
    hull = cv2.convexHull(points.astype(np.float32)).reshape(-1, 2).astype(float)
    if hull.shape[0] < 4:
        return None
    D = ((hull[:, None] - hull[None]) ** 2).sum(-1)
    i, k = np.unravel_index(int(np.argmax(D)), D.shape)
    a, b = hull[i], hull[k]
    t = (b - a) / max(float(np.hypot(*(b - a))), 1e-9)
    side = (hull - a) @ np.array([-t[1], t[0]])
    if side.max() < 1.0 or side.min() > -1.0:
        return None
    v = np.array([a, hull[int(np.argmax(side))], b, hull[int(np.argmin(side))]])
    return v[clockwise_from_left(v)]


def _disc(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def halo_mask(crop: np.ndarray, marker: np.ndarray, lut: np.ndarray, vector: np.ndarray
              ) -> np.ndarray:
    """The pixels of a BGR crop that are the marker's colour, or it plus white light (bool
    mask): ``colour.lit_marker_mask``, its least chroma ``HALO_MIN_CHROMA`` times the median
    chroma of the ``marker`` pixels (bool mask: the seed's piece of the blob; a share of
    that where a channel clips). A highlight's washed-out halo fails the colour test but
    keeps the marker's chroma score (the model's). In float32 (a crop of up to
    ``MAX_WINDOW_PX`` a side; a colour on the ellipse's rim may round the other way)."""
    lin = lut.astype(np.float32)[crop]
    seed = lin[marker]
    seed_chroma = float(np.median(seed.sum(axis=1) - 3.0 * seed.min(axis=1)))
    return lit_marker_mask(lin, vector, HALO_MIN_CHROMA * seed_chroma)


def _blob(crop: np.ndarray, white: np.ndarray, seed: tuple[int, int], lut: np.ndarray,
          vector: np.ndarray, green_bound: np.ndarray, halo: bool = False
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | str:
    """In a BGR crop with its white (every channel at least the trigger's level: bool
    mask), the seed's blob's marker-coloured pixels (its pieces joined across clipped ones;
    where ``halo``, with the highlight's halo, ``halo_mask``), the crop's clipped pixels (some
    channel clipped) and the blob's (bool masks); or why not: white must lie on the blob or
    within ``WHITE_NEAR_PX`` of it."""
    b, g, r = cv2.split(crop)
    clipped = cv2.max(cv2.max(b, g), r) >= CLIPPED_LEVEL
    marker = grid_mask(crop, 1, 0, lut, vector, green_bound)[0] > 0
    ys, xs = np.nonzero(marker)
    if xs.size == 0:
        return NO_BLOB
    near = cv2.dilate(clipped.astype(np.uint8), _disc(JOIN_PX))
    j = int(np.argmin((xs - seed[0]) ** 2 + (ys - seed[1]) ** 2))  # (the seed's nearest)
    if halo:  # (the pieces joined across the halo too; the fit's marker pixels as before)
        _, pieces = cv2.connectedComponents(marker.astype(np.uint8), connectivity=8)
        near |= halo_mask(crop, pieces == pieces[ys[j], xs[j]], lut, vector).astype(np.uint8)
    _, labels = cv2.connectedComponents(marker.astype(np.uint8) | near, connectivity=8)
    blob = labels == labels[ys[j], xs[j]]
    if not (cv2.dilate(blob.astype(np.uint8), _disc(WHITE_NEAR_PX)) & white).any():
        return NO_HIGHLIGHT  # (no white core on it or beside it: an over-exposed ink)
    return blob & marker, clipped, blob & clipped


def _window(image: np.ndarray, seed: tuple[int, int], level: int, whole: bool,
            lut: np.ndarray, vector: np.ndarray, green_bound: np.ndarray
            ) -> tuple[np.ndarray, tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]
                       ] | str:
    """The crop of ``image`` within ``WINDOW_PX`` of ``seed`` (x, y px), its corner (x, y
    px) and ``_blob``'s masks in it (white: every channel at ``level`` or more); or why not.
    Where ``whole`` (a fit from the blob, not a check: the halo joins the blob's pieces), a
    blob that reaches the crop's side inside the image is looked for again in a crop
    ``MARGIN_PX`` beyond it on its other sides and ``WINDOW_PX`` beyond it on the side it
    reached, until it reaches none; refused where the crop would be over ``MAX_WINDOW_PX`` a
    side: a marker cut by the window is fitted to a part of it (seed 7, view 117: a vertex
    5.7 px off)."""
    H, W = image.shape[:2]
    x0, y0 = max(seed[0] - WINDOW_PX, 0), max(seed[1] - WINDOW_PX, 0)
    x1, y1 = min(seed[0] + WINDOW_PX + 1, W), min(seed[1] + WINDOW_PX + 1, H)  # (exclusive)
    while True:
        if x1 <= x0 or y1 <= y0:
            return NO_BLOB
        crop = np.ascontiguousarray(image[y0:y1, x0:x1])
        crop.flags.writeable = False  # (the kernels' compiled type: the frames')
        white = cv2.inRange(crop, (level,) * 3, (255, 255, 255))
        if not cv2.countNonZero(white):
            return NO_HIGHLIGHT  # (the common case, first and cheaply: no white near)
        found = _blob(crop, white, (seed[0] - x0, seed[1] - y0), lut, vector, green_bound,
                      halo=whole)
        if isinstance(found, str) or not whole:
            return found if isinstance(found, str) else (crop, (x0, y0), found)
        ys, xs = np.nonzero(found[0] | found[2])
        bx0, bx1 = int(xs.min()) + x0, int(xs.max()) + x0  # (the blob's box, image px)
        by0, by1 = int(ys.min()) + y0, int(ys.max()) + y0
        cut = (bx0 == x0 > 0, by0 == y0 > 0, bx1 == x1 - 1 < W - 1, by1 == y1 - 1 < H - 1)
        if not any(cut):
            return crop, (x0, y0), found
        reach = [WINDOW_PX if c else MARGIN_PX for c in cut]
        x0, y0 = max(bx0 - reach[0], 0), max(by0 - reach[1], 0)
        x1, y1 = min(bx1 + reach[2] + 1, W), min(by1 + reach[3] + 1, H)
        if max(x1 - x0, y1 - y0) > MAX_WINDOW_PX:
            return (f"the marker's blob reaches past the fit's window ({crop.shape[1]} x "
                    f"{crop.shape[0]} px; at most {MAX_WINDOW_PX} px a side)")


def fit(image: np.ndarray, seed: tuple[int, int], lut: np.ndarray, vector: np.ndarray,
        green_bound: np.ndarray, camera: CameraModel | None = None,
        model_m: np.ndarray | None = None, start_px: np.ndarray | None = None,
        assumed: Sequence[CameraModel] | None = None) -> HighlightFit | str:
    """The marker at ``seed`` (x, y px) in a BGR uint8 image, under a clipped highlight,
    fitted whole; or why not (a string). ``lut``, ``vector``, ``green_bound``: the colour
    model's (``colour.ColourModel``). With the ``camera`` and the rhombus ``model_m`` (4, 3)
    m (left, top, right, bottom), a free fit refused for an edge under the highlight or for
    a vertex's uncertainty over ``MAX_SIGMA_PX`` is fitted again as the rhombus's pose,
    what its edges show fixing it (``_fit_pose``); with ``model_m`` and no ``camera``, under
    the cameras ``assumed`` (default: those ``assumed_camera`` gives for
    ``ASSUMED_FOCAL_W``; the extractor's learned camera's band, ``learned_camera.py``),
    taken where they agree. ``start_px``: the scans' vertices (4, 2) px, left, top, right,
    bottom, to start from, as a check of them (its caller judges the uncertainty: no
    ``MAX_SIGMA_PX`` and no pose fit; a box over ``shadow.MAX_BOX_PX`` is not checked);
    else the blob's hull."""
    H, W = image.shape[:2]
    # (a last resort: a glossy print's glow short of clipping, the marker with its halo)
    level = CLIPPED_LEVEL if start_px is not None else GLOW_LEVEL
    windowed = _window(image, seed, level, start_px is None, lut, vector, green_bound)
    if isinstance(windowed, str):
        return windowed
    crop, (cx0, cy0), found = windowed
    marker, clipped, core = found
    if start_px is None:
        ys, xs = np.nonzero(marker | core)  # (a core over a vertex: the hull reaches it)
        v0 = extreme_points(np.column_stack([xs, ys]))
        if v0 is None:
            return "the blob is too thin for a quadrilateral"
    else:
        v0 = np.asarray(start_px, float) - [cx0, cy0]
    x0, y0 = (max(int(z), 0) for z in np.floor(v0.min(0) - MARGIN_PX))
    x1 = min(int(np.ceil(v0[:, 0].max() + MARGIN_PX)), crop.shape[1] - 1)
    y1 = min(int(np.ceil(v0[:, 1].max() + MARGIN_PX)), crop.shape[0] - 1)
    # a marker whose box is over shadow.MAX_BOX_PX: every step-th row and column (its cost);
    # not as a check (its pixels' fit then moved good vertices 1.2-4.9 px on seeds 200-209)
    step = math.ceil(math.sqrt((x1 - x0 + 1) * (y1 - y0 + 1) / shadow.MAX_BOX_PX))
    if step > 1 and start_px is not None:
        return f"the marker's box is over {shadow.MAX_BOX_PX} px² (not checked)"
    masked = cv2.dilate(clipped[y0:y1 + 1, x0:x1 + 1].astype(np.uint8), _disc(MASK_PX)) > 0
    lin = lut[crop[y0:y1 + 1, x0:x1 + 1]]
    ink = marker[y0:y1 + 1, x0:x1 + 1] & ~masked
    if ink.sum() < MIN_MARKER_PX:
        return f"fewer than {MIN_MARKER_PX} unclipped marker pixels"
    q = np.median(lin[ink], axis=0)
    S = lin @ chroma_direction(q[0], q[1], q[2])
    Y, X = np.mgrid[y0:y1 + 1, x0:x1 + 1].astype(float)
    seen = ~masked
    used = seen.copy()
    if step > 1:
        used[:] = False
        used[::step, ::step] = seen[::step, ::step]
    x, y, s = X[used], Y[used], S[used]
    surround = S[used & ~marker[y0:y1 + 1, x0:x1 + 1]]
    if surround.size < MIN_MARKER_PX:
        return "too little surround around the marker"
    b0 = float(np.median(surround))
    f_scale = max(1.5 * float(np.median(np.abs(surround - b0))), 0.5)
    blur0 = START_BLUR_PX if start_px is None else CHECK_START_BLUR_PX
    p0 = np.array([*v0.ravel(), blur0 - 0.3, float(np.median(S[ink])) - b0, b0])

    def residual(p: np.ndarray, jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        f, J = shadow.model(np.r_[p, 1.0, 0.0, 0.0, 0.0], x, y, jac)  # k = 1: no shadow
        return f - s, (J[:, :11] if J is not None else None)

    solved = shadow.robust_lm(residual, p0, f_scale, MAX_EVALUATIONS)
    if solved is None:
        return f"the fit did not converge in {MAX_EVALUATIONS} evaluations"
    p, r, J = solved
    if not (np.isfinite(p).all() and p[9] > 0):
        return "the fit lost the marker"
    order = clockwise_from_left(p[:8].reshape(4, 2))
    v = p[:8].reshape(4, 2)[order]
    blur = abs(p[8]) + 0.3
    if blur > MAX_BLUR_PX:
        return f"the edges' fitted blur {blur:.1f} px is over {MAX_BLUR_PX} px (not a clean step)"
    seen_share = _seen_share(v, seen, x0, y0)
    corner = np.array([cx0, cy0], float)  # (the crop's, in the image)
    least = int(np.argmin(seen_share))
    hidden = least if seen_share[least] < MIN_SUPPORT else -1  # (the edge not measured)
    if hidden >= 0:
        free: np.ndarray | str = (
            f"the {EDGE_NAMES[least]} edge is under the highlight over "
            f"{1 - seen_share[least]:.0%} of its length (at most {1 - MIN_SUPPORT:.0%})")
    else:
        worst, edge = shadow.band_rms(v, x, y, r, float(p[-2]), MAX_BAND_RMS)
        if edge >= 0:
            return (f"the {EDGE_NAMES[edge]} edge does not fit the marker (band RMS "
                    f"{worst:.3f} of its level)")
        free = shadow.vertex_covariance(r, J, f_scale, SIGMA_SCALE, SIGMA_FLOOR_PX)
        if isinstance(free, str):
            return free
        sigma = math.sqrt(float(free[:, 0, 0].max()))
        if start_px is None and sigma > MAX_SIGMA_PX:
            free = (f"a vertex's uncertainty {sigma:.2f} px is over {MAX_SIGMA_PX} px "
                    f"(extrapolated under the highlight)")
    if not isinstance(free, str):
        return HighlightFit(v + corner, free[order], worst * blur * math.sqrt(2.0 * math.pi))
    if model_m is None or start_px is not None:
        return free

    def as_pose(cam: CameraModel) -> HighlightFit | str:
        tie = POSE_TIE if cam is camera else POSE_TIE_ASSUMED
        # (under the cameras assumed, the edges seen must be three: seen_in)
        seen_in = (seen, x0, y0) if camera is None and assumed is None else None
        return _as_pose(residual, p, v, least, hidden, cam, model_m, corner, f_scale, x, y, tie,
                        seen_in)
    if camera is not None:
        posed = as_pose(camera)
        return posed if not isinstance(posed, str) else f"{free}; as the rhombus's pose: {posed}"
    # no intrinsics: the pose under each assumed camera; where they agree, their mean, their
    # spread in the uncertainty
    fits: list[HighlightFit] = []
    learned = assumed is not None
    cameras = assumed if assumed is not None else [assumed_camera(W, H, focal_w)
                                                   for focal_w in ASSUMED_FOCAL_W]
    for cam in cameras:
        posed = as_pose(cam)
        if isinstance(posed, str):
            how = "the camera learned from the marker at" if learned else "assumed"
            return (f"{free}; as the rhombus's pose (no intrinsics; focal length {how} "
                    f"{cam.K[0, 0] / W:.3g} x the width): {posed}")
        fits.append(posed)
    ends = np.array([f.vertices_px for f in fits])
    half = np.linalg.norm(ends - ends.mean(0), axis=2).max(0)  # px, each vertex
    cov = np.max([f.cov_px2 for f in fits], axis=0) + (half ** 2)[:, None, None] * np.eye(2)
    if (sigma := recover.largest_sigma_px(cov)) > MAX_POSE_SIGMA_PX:
        return (f"{free}; as the rhombus's pose (no intrinsics): a vertex's uncertainty "
                f"{sigma:.2f} px over the focal lengths "
                f"{'of the camera learned from the marker' if learned else 'assumed'} is over "
                f"{MAX_POSE_SIGMA_PX} px")
    return HighlightFit(ends.mean(0), cov, max(f.residual_px for f in fits))


def assumed_camera(width: int, height: int, focal_w: float) -> CameraModel:
    """A camera of ``width`` x ``height`` px with no distortion, square pixels, the principal
    point at the image's centre and a focal length of ``focal_w`` times the width (px)."""
    return CameraModel.pinhole(focal_w * width, 0.5 * (width - 1), 0.5 * (height - 1), width,
                               height)


def _as_pose(residual: Callable[[np.ndarray, bool], tuple[np.ndarray, np.ndarray | None]],
             p: np.ndarray, v: np.ndarray, least: int, hidden: int, camera: CameraModel,
             model_m: np.ndarray, corner: np.ndarray, f_scale: float, x: np.ndarray,
             y: np.ndarray, tie: float,
             seen_in: tuple[np.ndarray, int, int] | None = None) -> HighlightFit | str:
    """The free fit (p, its vertices v in the crop at ``corner``) fitted again as the rhombus
    ``model_m`` seen by ``camera`` (``_fit_pose``, ambiguous within ``tie``) and judged
    (blur, the edges' bands but ``hidden``'s, ``MAX_POSE_SIGMA_PX``); or why not. With
    ``seen_in`` (the fit's seen pixels and its box's corner in the crop), a pose with a
    second edge seen under ``MIN_SECOND_SUPPORT`` of its length is refused too."""
    posed = _fit_pose(residual, p, v, least, camera, model_m, corner, f_scale, tie)
    if isinstance(posed, str):
        return posed
    p, r, J, v, to_vertices = posed
    if seen_in is not None:
        share = _seen_share(v, *seen_in)
        if share[(second := int(np.argsort(share)[1]))] < MIN_SECOND_SUPPORT:
            return (f"the {EDGE_NAMES[second]} edge is under the highlight too (seen over "
                    f"{share[second]:.0%} of its length): two edges hidden")
    if (blur := abs(p[-3]) + 0.3) > MAX_BLUR_PX:
        return f"its fitted blur {blur:.1f} px is over {MAX_BLUR_PX} px"
    worst, edge = shadow.band_rms(v, x, y, r, float(p[-2]), MAX_BAND_RMS, hidden)
    if edge >= 0:
        return (f"the {EDGE_NAMES[edge]} edge does not fit the marker (band RMS {worst:.3f} of "
                "its level)")
    cov = shadow.vertex_covariance(r, J, f_scale, SIGMA_SCALE, SIGMA_FLOOR_PX, to_vertices)
    if isinstance(cov, str):
        return cov
    if (sigma := math.sqrt(float(cov[:, 0, 0].max()))) > MAX_POSE_SIGMA_PX:
        return f"a vertex's uncertainty {sigma:.2f} px is over {MAX_POSE_SIGMA_PX} px"
    return HighlightFit(v + corner, cov, worst * blur * math.sqrt(2.0 * math.pi))


def _fit_pose(residual: Callable[[np.ndarray, bool], tuple[np.ndarray, np.ndarray | None]],
              p: np.ndarray, v: np.ndarray, hidden: int, camera: CameraModel,
              model_m: np.ndarray, corner: np.ndarray, f_scale: float, tie: float = POSE_TIE
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | str:
    """The marker fitted (``residual`` of the 11 parameters p: vertices px in the crop,
    blur, level, floor) as the rhombus ``model_m`` seen by ``camera``: 9 parameters (the
    rotation vector, the translation (m), blur, level, floor), started from the poses that
    put its edges on three edges of the free fit v (left, top, right, bottom; all but
    ``hidden``, the one seen least: ``recover.p3l``) and from IPPE on v. The parameters, residual,
    Jacobian, vertices (4, 2) px in the crop and their derivatives by the pose (8, 6); or why
    not."""
    K, dist = camera.K, camera.dist
    obj = np.ascontiguousarray(model_m, np.float64)

    def vertices(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        px, jac = cv2.projectPoints(obj, q[:3], q[3:6], K, dist)
        return px.reshape(4, 2) - corner, jac[:, :6]

    def posed(q: np.ndarray, jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        w, dw = vertices(q)
        f, J = residual(np.r_[w.ravel(), q[6:]], jac)
        if J is None:
            return f, None
        return f, np.hstack([J[:, :8] @ dw, J[:, 8:]])

    lines = [None if e == hidden else (v[e] + corner, v[(e + 1) % 4] - v[e]) for e in range(4)]
    starts = recover.p3l(recover.edge_normals(lines, camera), obj, hidden)
    status, Rs, ts, _, count = ippe4(obj, np.ascontiguousarray(undistort_px(camera, v + corner)))
    starts += [(Rs[i], ts[i]) for i in range(count)] if status == OK else []

    def cost(r: np.ndarray) -> float:
        return float(np.sum(np.sqrt(1.0 + (r / f_scale) ** 2) - 1.0))

    first: list[tuple[float, int, np.ndarray]] = []
    for R, t in starts:
        if (obj @ R.T + t)[:, 2].min() <= 0.0:
            continue
        q0 = np.r_[cv2.Rodrigues(R)[0].ravel(), t, p[8:]]
        first.append((cost(posed(q0, False)[0]), len(first), q0))
    fits: list[tuple[float, int, tuple[np.ndarray, np.ndarray, np.ndarray]]] = []
    for _, _, q0 in sorted(first, key=lambda f: f[:2])[:POSE_STARTS]:
        solved = shadow.robust_lm(posed, q0, f_scale, MAX_EVALUATIONS)
        if solved is not None and np.isfinite(vertices(solved[0])[0]).all():
            fits.append((cost(solved[1]), len(fits), solved))
    if not fits:
        return ("no pose puts the rhombus on its three edges seen best" if not first else
                f"the fit did not converge in {MAX_EVALUATIONS} evaluations")
    fits.sort(key=lambda f: f[:2])
    q, r, J = fits[0][2]
    w, dw = vertices(q)
    for c, _, other in fits[1:]:
        apart = float(np.linalg.norm(vertices(other[0])[0] - w, axis=1).max())
        if c <= (1.0 + tie) * fits[0][0] and apart > POSE_APART_PX:
            return (f"two poses fit its seen edges alike (costs {c / fits[0][0] - 1:.1%} "
                    f"apart), their vertices {apart:.1f} px apart")
    return q, r, J, w, dw


def _seen_share(v: np.ndarray, seen: np.ndarray, x0: int, y0: int, samples: int = 40
                ) -> np.ndarray:
    """Each edge's (v[i] to v[i + 1], px in the crop) share of ``samples`` points over its
    middle 90 % that fall on seen (not masked) pixels of the box at (x0, y0); outside the
    box: not seen."""
    t = np.linspace(0.05, 0.95, samples)[:, None]
    h, w = seen.shape
    share = np.zeros(4)
    for i in range(4):
        pts = np.rint(v[i] + t * (v[(i + 1) % 4] - v[i]) - [x0, y0]).astype(np.int64)
        inside = (pts[:, 0] >= 0) & (pts[:, 0] < w) & (pts[:, 1] >= 0) & (pts[:, 1] < h)
        pts = pts[inside]
        share[i] = float(seen[pts[:, 1], pts[:, 0]].sum()) / samples
    return share
