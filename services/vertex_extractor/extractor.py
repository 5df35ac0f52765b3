"""Rhombus vertices from one frame: the paper's scan-line method (section 4.1), sub-pixel.

The paper (Table 1) walks from a seed pixel column by column, Δx apart, collecting for each
column the upper and lower edge points U_k and D_k until a column is shorter than MIN_LEN; then
(Table 2) assigns the U points to two lines (left and right of the top vertex) and likewise the
D points, fits each by least squares, and intersects the four lines into the vertices.

Where we depart from the paper, keeping its spirit:
- The seed is the previous frame's marker centre when tracking; otherwise a coarse 1-in-8 pixel
  grid search finds the marker without testing the whole frame.
- The walk is incremental (each column's run found from the previous column's ends) and
  compiled (``scan.py``): its cost is the marker's width, not its area or the frame's size.
  One seed's scans, fits, tests and cross-check below run in one compiled call
  (``measure.py``); Python only words a refusal's reason.
- Edge points are sub-pixel: the colour score is linear in the marker's coverage of a pixel,
  so the sum of coverages over a window across the edge gives the edge position exactly on
  area-sampled images.
- Table 2's greedy, order-dependent assignment is replaced by the optimal split (least total
  residual over all split points, from prefix moments) and total-least-squares fits with
  Huber weights (``lines.py``); columns at the split are dropped (their window straddles a
  vertex).
- Both levels of each edge point's sum are local (``scan._edge``): a shadow's boundary across
  the marker moves no edge; where the inside level steps along an edge (the boundary crosses
  it) or no contrast is left (a clipped highlight, an occluder), the point is dropped; so is
  a point whose coverage sum and half-way crossing disagree (``scan._crossing_gap``: a
  shaded strip of the rim inside its window, where a shadow's boundary meets the edge). A
  shaded marker's inside level is read nearer its edges where they are sharp
  (``shaded_inside_depth``, ``scan._sharpness``), and there follows the light's steady
  change across each edge, a soft shadow's penumbra (``shaded_gradient``,
  ``scan._gradient``).
- A glossy print's highlight: the walk goes on through its halo (the marker's colour plus
  white light, ``colour.is_lit_marker``), and edge points are left out where a run ends on
  the clipped core or the ink inside the window clips (``scan._at_highlight``,
  ``scan._clipped_halo``); two blobs of one marker (split by a highlight or an arm) are not
  ambiguous.
- Each line is fitted robustly (``lines.robust_line``: Huber, then Tukey's biweight from the
  better of it and the middle half), the split moved to where the two lines meet: an arm over
  a vertex or part of an edge is left out and the vertex comes from the visible lines; a line
  with fewer than half its points on it, or many points outside the quadrilateral, refuses.
  Where the points as they are fail, they are tried again without a notch in the outline
  (``lines.on_hull``: the marker is convex, so points deep inside their chain's hull are
  something in front of it), unless the notch is a clipped highlight (``scan.notch_kept``).
- A plausibility check (convex, sensible angles, enough points per edge, small residual, area
  consistent with the blob, up to 30 % hidden) and a shape test: by weak perspective, the
  quadrilateral must be the deployment's rhombus seen at most ``max_off_normal_deg`` off its
  normal, rolled at most ``max_roll_deg`` and turned at most ``max_pitch_deg`` about its
  horizontal axis (a level camera at about the marker's height), so that a card, a square or
  a wide rhombus in the same ink is refused; and its diagonals must cross near their
  midpoints, as they do for the rhombus seen from no nearer than the working distance
  (``lines.diagonal_shift``, ``nearest_view_m``: an arm's straight edge across a vertex,
  taken for an edge, shifts them far more). With the camera's intrinsics
  (``use_intrinsics``) the best planar pose of the rhombus must also reproject the vertices
  and view it as the deployment can (``shape.py``). Each edge must be a clean step: a
  shadow's boundary running along an edge just inside the marker moves the whole edge by a
  steady 1-3 px, which the median profile across it shows (``profile.py``); next to each
  visible vertex, each edge must step where the others do (``profile.vertex_steps``: a
  shadow's boundary near a vertex bends the points there and the lines miss the vertex).
  Anything else is ``found = False`` with a reason.
- A marker whose column scan alone is too uncertain (a vertex under a highlight or a
  shadow, edges crossed at a glancing angle) is scanned along its rows too; if the two
  agree, each vertex is their mean weighted by the inverse of each one's variance
  (``measure.fuse``, ``fuse_scans``), and the result's uncertainty is judged. Where that
  is still too uncertain and a highlight clips to white in the marker's box (it took edge
  points away), each edge is fitted to both scans' points at once (``lines.fit_joint``,
  ``joint_fit``: more points, further apart) and judged again; not under a shadow, whose
  bias more points do not cure. A marker under a clipped highlight whose column and row
  lines both failed (too few points on an edge of either scan alone: a vertex or much of an
  edge washed out) is fitted to both scans' points at once too, split where each chain turns
  (``measure._under_highlight``, ``both_scans_under_highlight``).
- A marker refused because its column and row scans disagree or an edge is not one step is
  tried once more with a 3 px window (``narrow_window``) under the same tests: a shadow's
  boundary a few px inside an edge falls in the 5 px window and moves the edge. Not one
  whose vertices are too uncertain or off their edges' steps: the narrower window left those
  as far off and reported them surer; and one whose column scan was too uncertain is found
  on the second try only if its row scan agrees (the column scan alone came out 5.5 px
  off at a reported 0.8 px under a highlight).
- Each detection carries its per-vertex covariance (px²): the line fits' offset and angle
  variances propagated through the intersections, scaled for the points' correlation
  (``COV_SCALE``); one whose largest sigma exceeds ``max_vertex_sigma_px`` is refused.
- A marker whose columns are too few (small), or a tall one whose column lines do not fit it
  (a steep view's near-vertical edges crossed at a glancing angle, an arm over a vertex), is
  scanned along its rows instead, under the same tests, then refused where the rows' lines
  miss the column scan's measured edge points by more than ``MAX_ROWS_OFF_PX``
  (``check_rows_instead``: a shadow over part of an edge tilts the rows' line through it)
  and else fitted with them too (``joint_rows_instead``); any other marker is scanned along
  its rows as well and the two results checked against each other (``measure.cross_check``):
  blur along the columns or a shadow's boundary inside one scan's window moves that scan's
  edges; the vertices are the two scans' mean, their
  disagreement grows the covariance, and a large one is refused.
- With the camera's intrinsics, a marker the line fits refuse for want of edge points (a
  highlight or an arm over an edge, a small or shaded marker) is fitted as the deployment's
  rhombus to the edge points it shows, where three of its edges fix the pose
  (``recover.py``), and passes the same tests; never on a tracked try.
- Last, on a cold try: a marker every route above refused is fitted whole to its pixels as
  the rhombus under a cast shadow's straight boundary (``shadow.py``: blurred edges times a
  half-plane's darkening, 15 parameters), and taken only where the fit and the surround
  both show that shadow, under the same shape tests and uncertainty limit
  (``shadow_model``; 20 ms at the median, paid only on such views). Where clipped white
  touches the blob, the same fit without the shadow, the pixels near the clipped ones left
  out, from the blob's hull: a glossy print's highlight that hides too much of an edge for
  the scans (``highlight.py``, ``highlight_model``; 20 ms at the median, up to 0.2 s); an
  edge under the highlight or a vertex too uncertain is given by the rhombus's pose (65 ms
  at the median, up to 0.8 s); without intrinsics, by its poses under two cameras where
  they agree (100 ms more at the median): the camera learned from the marker's own
  detections, its focal length ± 3 % (``learned_camera.py``, ``learn_camera``), or before it
  is learned, two assumed focal lengths.
- A marker the scans found (cold or tracked) with clipped white near a vertex is checked by
  that fit started from its vertices: where it moves a vertex by more than a pixel, its
  vertices are reported instead, or the marker is refused where the fit is unsure of any
  vertex (``_checked_under_highlight``; 21 ms at the median).
- A marker the scans found (cold or tracked) but report unsure of, a vertex's sigma over
  ``shadow.CHECK_SIGMA_PX``, or with the marker's colour just beyond an edge (over
  ``shadow.CHECK_BEYOND_SHARE`` of the pixels ``profile.marker_beyond`` reads: a shadow's
  boundary inside the marker taken for that edge), is checked by the whole-marker shadow fit
  started from its vertices: refused where that fit is taken and puts a vertex over
  ``shadow.CHECK_APART_PX`` away (a shadow's boundary moved the scans' edges), and then not
  fitted whole again (``_checked_under_shadow``; a fit where a shadow crosses the marker, 20
  ms at the median).
- The covariance reported (``covariance.py``) is that one scaled with the marker's size (the
  errors that matter do not average out along an edge) plus what the profile says about a
  misplaced edge: honest (NEES about 2) on small and large markers, under blur and shadows.

Limits: one marker per frame (two similar blobs on a cold search are refused as ambiguous);
without intrinsics the shape test cannot tell the marker from a rhombus of another shape
that is a view of it (a narrower one seen face on is the marker turned about its vertical
axis), and with them only where the view is far from affine (near, large); a marker
measured by the row scan alone (too narrow for the columns) is checked only against the
stretches of its edges the columns did measure, one whose row scan fails is not
cross-checked, and a shadow's boundary near a vertex can still move both scans.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace
from typing import Literal

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from services.core.camera import CameraModel
from services.core.mounts import Geometry
from services.vertex_extractor import (
    covariance,
    highlight,
    lines,
    measure,
    paper,
    profile,
    quad_model,
    recover,
    scan,
    shadow,
    shape,
)
from services.vertex_extractor.colour import ColourModel, grid_mask
from services.vertex_extractor.learned_camera import CameraLearner, Solved
from services.vertex_extractor.shape import ShapeParams, ShapeTest


class ExtractorParams(BaseModel):
    """The extractor's parameters (the service's settings are exactly these); the only place
    their defaults are defined."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    colour: ColourModel = Field(default_factory=ColourModel,
                               description="which pixels are the marker (linear light)")
    dx: int = Field(default=1, ge=1, le=8, description="column step Δx (px)")
    max_columns: int = Field(
        default=64, ge=0, le=4096, description="a marker with more usable columns (or rows) "
        "is measured first on every k-th, the least k that leaves at most this many, and "
        "taken so if both scans find it and agree; else on every column (0: always every "
        "column). A near marker's scans cost about what a far one's do: tracked 0.17 -> "
        "0.12 ms at 640x480, 0.34 -> 0.16 ms at 1920x1080 (docs/measured.md)")
    min_len_px: int = Field(default=12, ge=4, description="MIN_LEN: shortest chord used (px)")
    window: int = Field(default=5, ge=2, le=12,
                        description="sub-pixel window: rows each side of the edge")
    outside_rows: int = Field(default=-1, ge=-1, le=12,
                              description="sub-pixel window rows outside the marker "
                                          "(-1: as many as window)")
    coarse_step: int = Field(default=8, ge=2, le=32, description="grid of the cold search (px)")
    min_area_px: float = Field(default=200.0, gt=0, description="smaller markers are refused")
    max_residual_px: float = Field(default=0.8, gt=0,
                                   description="edge points farther off their line: not straight")
    min_points_per_edge: int = Field(default=4, ge=2, description="fewer: partly hidden")
    small_min_len_px: int = Field(default=8, ge=4, description="MIN_LEN on a second try when "
                                  "the marker is too small for the first (25-40 px markers)")
    small_min_points_per_edge: int = Field(
        default=3, ge=2, description="min_points_per_edge on the small markers' second try")
    small_window: int = Field(
        default=3, ge=2, le=12, description="window on the second try of a marker whose blob "
        "is under small_window_area_px: a narrower footprint at its short chords")
    small_window_area_px: float = Field(
        default=800.0, gt=0, description="a blob smaller than this (px², about 40 x 40 px "
        "across) is tried again with small_window (larger ones keep window: a highlight's "
        "blob is small too, and its edges are read better with the wider one)")
    narrow_window: int = Field(
        default=3, ge=2, le=12, description="window on the second try of a marker whose "
        "column and row scans disagree or one of whose edges is not one step: a shadow's "
        "boundary a few px inside an edge falls in the wider window and moves the edge")
    fuse_scans: bool = Field(
        default=True, description="a marker whose column scan alone is too uncertain (its "
        "edges crossed at a glancing angle, a vertex under a highlight) is measured from the "
        "column and row scans' vertices weighted by their uncertainty, if the two agree; "
        "false: refused")
    joint_fit: bool = Field(
        default=True, description="where the two scans' weighted vertices are still too "
        "uncertain and a highlight clips in the marker's box, each edge is fitted to both "
        "scans' points at once (more points, further apart) and the result judged again; "
        "false: refused")
    shaded_spread: float = Field(
        default=scan.SHADED, gt=0.0, description="a marker whose columns' centres spread by "
        "more than this share of the brightest is shaded (a cast shadow over part of it): "
        "each edge point then takes its local inside level (over the neighbouring columns), "
        "the whole chain's being off by the shadow's gradient; in even light the chain's, "
        "where the local one is within 8 % of it (the JPEG's blocks move the local one "
        "about); 1 or more: never shaded (the spread is at most 1)")
    shaded_inside_depth: int = Field(
        default=scan.SHADED_DEPTH, ge=0, le=12, description="a shaded marker's inside level "
        "is read this many rows inside each run's end, not just beyond the window, where its "
        "edges are sharp (a shadow's gradient or boundary then lies between the level and "
        "the edge less often; under blur beyond the window, as elsewhere); 0, or not less "
        "than the window + 1: beyond the window")
    shaded_gradient: bool = Field(
        default=True, description="where a shaded marker's inside level is read nearer its "
        "edges, it also follows the light's steady change across each edge (a soft "
        "shadow's penumbra), from two deeper bands of rows; false: one level for the "
        "whole window")
    both_scans_under_highlight: bool = Field(
        default=True, description="a marker under a clipped highlight whose column and row "
        "lines both failed (a vertex or much of an edge washed out: too few points on an "
        "edge of either scan alone) is fitted to both scans' points at once, split where "
        "each chain turns, on the small markers' second try or after the other tries; "
        "false: refused")
    check_rows_instead: bool = Field(
        default=True, description="a marker measured along its rows because its column "
        "lines failed (too few points on an edge, a steep view) is refused where the rows' "
        "lines are off the column scan's measured edge points (a shadow over part of an "
        "edge tilts the rows' line there); false: the rows' result as it is")
    joint_rows_instead: bool = Field(
        default=True, description="such a marker's edges are then fitted to both scans' "
        "measured points at once (the columns' points pull back an edge that a shadow over "
        "part of it tilted in the rows), where that passes every test; false: the rows' "
        "lines alone")
    small_min_area_px: float = Field(
        default=120.0, gt=0, description="min_area_px on the small markers' second try (px²)")
    min_angle_deg: float | None = Field(
        default=None, gt=0, lt=90, description="sharper corners are implausible (deg); "
        "unset: the marker's own sharpest corner seen max_off_normal_deg off its normal, "
        "x 0.8 for perspective (17.7 deg for the default 5.0 x 6.6 cm marker; a fixed 25 deg "
        "refused a 6 x 10 cm marker's views from 68 deg)")
    max_off_normal_deg: float = Field(
        default=75.0, gt=0, lt=90, description="views further off the marker's normal are "
        "refused (the quadrilateral is then more likely something else)")
    max_roll_deg: float = Field(default=30.0, gt=0, le=180,
                                description="largest roll of the marker in the image")
    max_pitch_deg: float = Field(
        default=30.0, gt=0, le=90,
        description="largest turn about the marker's horizontal axis (its vertical diagonal "
                    "foreshortened): small when the camera and the marker stand upright at "
                    "similar heights; raise it for a camera looking down")
    nearest_view_m: float = Field(
        default=0.15, gt=0.0, description="the nearest the camera comes to the marker (m): "
        "a quadrilateral whose diagonals cross further off their midpoints than the marker "
        "seen from there allows is refused (the rhombus of longer half-diagonal h at depth Z: "
        "at most h / 2Z of each diagonal, however turned; x 1.35 for the depth at the "
        "image's corners: 15 % for the default 6.6 cm marker from 15 cm, the webcam renders "
        "at 15-80 cm reach 8.7 %); a vertex cut off by an arm's straight edge, taken for an "
        "edge, shifts them further")
    max_vertex_sigma_px: float = Field(
        default=1.2, gt=0, description="a detection whose line fits' vertex uncertainty (1 "
        "sigma, largest axis) exceeds this is refused; the uncertainty reported with a found "
        "one adds what the profiles across its edges show (covariance.py), and may exceed it")
    max_step_offset_px: float = Field(
        default=0.5, gt=0, description="an edge whose median profile crosses half way "
        "further than this inside its fitted line (1.6 times this beyond it), and further "
        "than max_step_spread_px from the four edges' median, is not a clean step (a "
        "shadow's boundary along it): the detection is refused (profile.py)")
    max_step_spread_px: float = Field(
        default=0.3, ge=0, description="see max_step_offset_px (a blurred marker's edges lie "
        "off their steps alike)")
    max_vertex_step_px: float = Field(
        default=1.0, gt=0, description="next to each visible vertex, each edge's profile "
        "must cross half way within this of the median of all such stretches (a shadow's "
        "boundary near a vertex moves it; profile.vertex_steps)")
    max_outside_share: float = Field(
        default=0.2, gt=0, le=1, description="share of one edge's points allowed outside the "
                                             "quadrilateral (beyond its line's noise band)")
    max_candidates: int = Field(default=6, ge=1, le=64,
                                description="blobs tried, largest first, on a cold search")
    method: Literal["ours", "paper"] = Field(
        default="ours", description="paper: Tables 1 and 2 as published (paper.py)")
    edge: Literal["local", "global", "crossing", "orthogonal"] = Field(
        default="orthogonal", description="sub-pixel edge method (scan.py; chosen by the bench)")
    shape: ShapeParams = Field(default_factory=ShapeParams, description=(
        "the shape test with intrinsics (camera/intrinsics): the best planar pose of the "
        "rhombus must reproject the vertices and view it as the deployment can"))
    shape_recovery: bool = Field(default=True, description=(
        "with intrinsics: a marker the line fits refuse for want of edge points (a "
        "highlight or an arm over an edge, a small or shaded marker; not one whose profile "
        "or shape test failed) is fitted as the deployment's rhombus to the edge points it "
        "shows, under the same uncertainty limit and the shape test's view bounds "
        "(recover.py)"))
    shadow_model: bool = Field(default=True, description=(
        "last, on a cold search: a marker every other route refused is fitted whole as the "
        "rhombus under a cast shadow's straight boundary, taken only where the fit and its "
        "surround show that shadow; and a marker the scans found but are unsure of (a vertex "
        "over 1.2 px, 1 sigma) or with its colour just beyond an edge is checked by that fit, "
        "and refused where it puts a vertex over 2 px away (shadow.py; 20 ms a view at the "
        "median, paid only on such views)"))
    highlight_model: bool = Field(default=True, description=(
        "last, on a cold search: a marker every other route refused, with clipped white "
        "on its blob, is fitted whole with the pixels near the clipped ones left out, taken "
        "only where every edge is seen over a fifth of its length and no vertex is too "
        "uncertain, else as the rhombus's pose that the edges seen fix (without intrinsics "
        "under two cameras, taken where they agree: the camera learned from the marker at its "
        "focal length +- 3 % (learn_camera), or before it is learned focal lengths 0.5 and "
        "1.4 times the frame's width); and a marker the scans "
        "found with clipped white near a vertex is checked by that fit, which replaces "
        "their vertices where it moves one by over 1 px, or refuses the marker where it is "
        "unsure of any vertex (highlight.py; 20 ms a fit at the median, up to 0.2 s, with "
        "the pose 65 ms, up to 0.8 s, with two assumed cameras 100 ms more; paid only on "
        "such views)"))
    learn_camera: bool = Field(default=True, description=(
        "without intrinsics, the camera is learned from the scans' confident detections of "
        "the marker (square pixels, no distortion: its focal length and principal point, "
        "learned_camera.py: after 40 distinct views, then every 20-80 new ones, a solve worked "
        "on over 10-20 frames, up to 6 ms each), and once the older and newer halves of its views "
        "agree, a marker "
        "under a highlight is fitted as the rhombus's pose under it (its focal length +- 3 %) "
        "instead of the two assumed cameras"))


_EDGES = {"global": scan.GLOBAL, "local": scan.LOCAL, "crossing": scan.CROSSING,
          "orthogonal": scan.ORTHOGONAL}


@dataclass(frozen=True)
class Detection:
    """Result for one frame. Vertices (4, 2) px, left, top, right, bottom, if found."""

    found: bool
    vertices_px: np.ndarray | None = None
    area_ratio: float = 0.0
    residual_px: float = 0.0
    reason: str = ""
    tracked: bool = False
    edge_points: tuple[np.ndarray, np.ndarray] | None = None  # U and D points (for plots)
    vertices_cov_px2: np.ndarray | None = None  # (4, 2, 2) per-vertex covariance, px²


@dataclass(frozen=True)
class _Refusal:
    """A cold try every scan refused: its refusal, and what the whole-marker fits start
    from (the seed, the first measurement's quadrilateral, the parameters, the shape test
    with intrinsics)."""

    det: Detection
    seed: tuple[int, int, int]
    first_v: np.ndarray
    prm: np.ndarray
    test: ShapeTest | None


def _miss(reason: str, tracked: bool = False) -> Detection:
    return Detection(False, reason=reason, tracked=tracked)


SAME_MARKER_PX = 3.0  # two detections whose vertices all lie this close are one marker


def _same_marker(a: Detection, b: Detection) -> bool:
    """Do two found detections (from two blobs of the cold search) measure one marker?"""
    assert a.vertices_px is not None and b.vertices_px is not None
    return bool(np.abs(a.vertices_px - b.vertices_px).max() < SAME_MARKER_PX)


class RhombusExtractor:
    """Stateful extractor: remembers the last marker to seed the next frame (tracking)."""

    def __init__(self, params: ExtractorParams | None = None,
                 diagonal_ratio: float | None = None, *, geometry: Geometry | None = None
                 ) -> None:
        """``geometry``: the deployment's mounts, whose marker's diagonals the shape tests
        take (default: the default ``Geometry``'s); ``diagonal_ratio``: the horizontal
        diagonal over the vertical one, if not the geometry's."""
        self.params = params or ExtractorParams()
        g = geometry or Geometry()
        if diagonal_ratio is None:
            diagonal_ratio = g.marker_width_m / g.marker_height_m
        self.diagonal_ratio = diagonal_ratio
        #: the rhombus (4, 3) m, left, top, right, bottom, with this diagonal ratio
        self._marker_m = g.marker_points() * [diagonal_ratio * g.marker_height_m
                                              / g.marker_width_m, 1.0, 1.0]
        #: the largest share of a diagonal by which the diagonals may cross off their
        #: midpoints (``lines.diagonal_shift``), from the marker seen from ``nearest_view_m``
        self.max_diagonal_shift = min(DIAGONAL_SHIFT_SLACK * 0.5 * max(
            g.marker_width_m, g.marker_height_m) / (2.0 * self.params.nearest_view_m), 0.5)
        #: corners sharper than this (deg) are implausible
        self.min_angle_deg: float = CORNER_SLACK * sharpest_corner_deg(
            diagonal_ratio, self.params.max_off_normal_deg) \
            if self.params.min_angle_deg is None else self.params.min_angle_deg
        p = self.params  # a small marker's second chance: shorter chords, fewer points
        self._small = p.model_copy(update=dict(
            min_len_px=min(p.min_len_px, p.small_min_len_px),
            min_points_per_edge=min(p.min_points_per_edge, p.small_min_points_per_edge),
            min_area_px=min(p.min_area_px, p.small_min_area_px)))
        self._prm = self._vector(p)
        self._prm_small = self._vector(self._small)
        self._seed: tuple[int, int, int] | None = None  # x, y, search radius (px)
        self._shape: ShapeTest | None = None
        #: the camera learned from the marker (no intrinsics; ``learn_camera``)
        self._learner: CameraLearner | None = None
        self._geometry = g
        #: the shape tests under the learned camera (``_learned_refusal``), for its solve
        self._learned_tests: tuple[Solved, list[ShapeTest]] | None = None
        self._loose = (self._prm, self._prm_small)  # the weak shape test's bounds, loosened

    def use_intrinsics(self, camera: CameraModel | None, geometry: Geometry | None = None
                       ) -> None:
        """Test each detection's shape against the deployment's rhombus seen by this camera
        (``shape.py``) on frames of the camera's size; None: the weak-perspective test alone
        (the default, and on frames of another size)."""
        self._shape = None if camera is None else ShapeTest(camera, geometry,
                                                                  self.params.shape)
        if camera is not None:  # (nothing is learned with intrinsics: ``_learn_from``)
            self._learner = None
        slack = self.params.shape.weak_slack_deg

        def loose(p: ExtractorParams) -> ExtractorParams:
            return p.model_copy(update=dict(
                max_off_normal_deg=min(p.max_off_normal_deg + slack, 89.0),
                max_roll_deg=min(p.max_roll_deg + slack, 180.0),
                max_pitch_deg=min(p.max_pitch_deg + slack, 90.0)))
        self._loose = (self._vector(loose(self.params)), self._vector(loose(self._small)))

    def _vector(self, p: ExtractorParams) -> np.ndarray:
        """``p`` as ``measure.measure`` takes it, with this deployment's shape limits."""
        return _params_vector(p, self.diagonal_ratio, self.max_diagonal_shift,
                              self.min_angle_deg)

    @property
    def intrinsics(self) -> CameraModel | None:
        return None if self._shape is None else self._shape.camera

    @property
    def learned_camera(self) -> Solved | None:
        """The camera learned from the marker (no intrinsics, ``learn_camera``), once the
        older and newer halves of the views it has kept agree; None before, or with
        intrinsics."""
        return None if self._learner is None else self._learner.camera()

    def reset(self) -> None:
        """Forget the last marker (the next frame is searched cold); the camera learned from
        the marker stays."""
        self._seed = None

    def extract(self, image: np.ndarray) -> Detection:
        """Find the rhombus in an H x W x 3 uint8 BGR image."""
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            return _miss(f"expected an H x W x 3 uint8 BGR image, got shape {image.shape} "
                         f"{image.dtype}")
        image = read_only(np.ascontiguousarray(image))
        if self._seed is not None:
            det = self._scanned(image, self._seed, tracked=True)[0]  # (no fit: a cold try's)
            if det.found:
                return self._learn_from(image, det)
        seeds = self._coarse_search(image)
        if isinstance(seeds, str):
            self._seed = None
            return _miss(seeds)
        det = self._learn_from(image, self._first_marker(image, seeds))
        if det.found and (why := self._learned_refusal(image, det)):
            self._seed = None
            return _miss(LEARNED_SHAPE + why)
        return det

    def _learned_refusal(self, image: np.ndarray, det: Detection) -> str:
        """Without intrinsics, once the camera is learned from the marker
        (``learned_camera.py``): why ``det`` is not an image of the deployment's rhombus
        under it (``shape.py``'s test) at its focal length and at both ends of its band
        (``learned_camera.BAND``); "" where it may be under any of them, or nothing is
        learned. On a cold search's detection only: two pink things that overlap into one
        blob pass the test without intrinsics (docs/measured.md "Two pink things that
        overlap"); a tracked marker was one a cold search took."""
        learner = self._learner
        if self._shape is not None or learner is None or det.vertices_px is None or \
                (learner.width, learner.height) != image.shape[1::-1]:
            return ""
        solved = learner.camera()
        if solved is None:
            return ""
        if self._learned_tests is None or self._learned_tests[0] is not solved:
            cameras = [solved.camera(learner.width, learner.height), *learner.cameras()]
            self._learned_tests = (solved, [ShapeTest(c, self._geometry, self.params.shape)
                                            for c in cameras])
        first = ""
        for test in self._learned_tests[1]:
            reason = test.refusal(det.vertices_px, det.vertices_cov_px2)
            if not reason:
                return ""
            first = first or reason
        return first

    def _learn_from(self, image: np.ndarray, det: Detection) -> Detection:
        """``det``, after the camera learner (no intrinsics, ``learn_camera``) has seen it if
        the scans found it (their edge points with it; not a whole-marker fit's)."""
        if not (det.found and self.params.learn_camera and self._shape is None
                and det.edge_points is not None and det.vertices_px is not None
                and det.vertices_cov_px2 is not None):
            return det
        H, W = image.shape[:2]
        if self._learner is None or (self._learner.width, self._learner.height) != (W, H):
            self._learner = CameraLearner(self._marker_m, W, H)  # (a new camera size)
        self._learner.add(det.vertices_px, det.vertices_cov_px2)
        return det

    def _first_marker(self, image: np.ndarray, seeds: list[tuple[int, int, int]]
                      ) -> Detection:
        """The one blob, largest first, that passes as the marker. Another blob that passes
        too, whatever its size, with edges about as straight (residual within 3x + 0.1 px),
        makes the frame ambiguous; otherwise the straighter one is the marker (a pink card that
        passes as the marker looks bigger or smaller with its distance: docs/measured.md "The
        marker's shape"). The whole-marker fits (under a highlight or a shadow) come after
        every blob's scans: a highlight splits a marker's blob, and its other piece's scans
        find it better; a blob they find is still compared with the others, fitted whole
        where their scans refuse them."""
        first: Detection | None = None
        refusals: list[_Refusal] = []
        for i, seed_px in enumerate(seeds):
            det, refusal = self._scanned(image, seed_px, tracked=False)
            if not det.found:
                first = first or det
                refusals += [refusal] if refusal is not None else []
                continue
            seed = self._seed
            # every other blob, fitted whole where its scans refuse it (the marker under a
            # shadow or a highlight, and this one a pink card?)
            others = itertools.chain(
                (self._fitted_whole_marker(image, refusal) for refusal in refusals),
                (self._extract_from(image, other_px) for other_px in seeds[i + 1:]))
            for other in others:
                if not other.found or _same_marker(det, other):
                    continue  # (a highlight or an arm splits one marker's blob in two)
                lo, hi = sorted((det.residual_px, other.residual_px))
                if hi < 3 * lo + 0.1:
                    self._seed = None
                    return _miss("two or more marker-like rhombi in view (ambiguous: no shape "
                                 "test tells which is the marker)")
                if other.residual_px < det.residual_px:
                    det, seed = other, self._seed
            self._seed = seed
            return det
        # no blob passed as the marker: each fitted whole, largest first (after every blob's
        # scans: a highlight splits a marker's blob, and the scans may find it from another)
        for refusal in refusals:
            fitted = self._fitted_whole_marker(image, refusal)
            if fitted.found:
                return fitted
            if refusal.det is first:
                first = fitted  # (the first blob's refusal, with why a fit was not taken)
        self._seed = None
        assert first is not None
        return first

    def _coarse_search(self, image: np.ndarray) -> list[tuple[int, int, int]] | str:
        """Seeds (x, y, search radius px) on the marker-coloured blobs of a 1-in-s pixel
        grid, largest first (at most ``max_candidates``)."""
        s = self.params.coarse_step
        colour = self.params.colour
        small, count, (i0, i1, j0, j1) = grid_mask(image, s, s // 2, colour.lut, colour.vector,
                                                   colour.green_bound)
        if count == 0:
            return "no marker-coloured pixels"
        if count > 0.5 * small.size:
            return "most of the frame is marker-coloured"
        # label only the marked cells' bounding box (with a border): the grid is mostly empty
        i0, j0 = max(i0 - 1, 0), max(j0 - 1, 0)
        box = np.ascontiguousarray(small[i0:i1 + 2, j0:j1 + 2])
        _, labels, stats, centroids = cv2.connectedComponentsWithStats(box, connectivity=8)
        areas = stats[1:, cv2.CC_STAT_AREA]
        seeds = []
        for k in np.argsort(areas)[::-1][:self.params.max_candidates]:
            label = int(k) + 1
            cx, cy = (int(c + 0.5) for c in centroids[label])
            if labels[cy, cx] != label:  # not convex: any cell of the blob
                ys, xs = np.nonzero(labels == label)
                cx, cy = int(xs[len(xs) // 2]), int(ys[len(ys) // 2])
            seeds.append((s // 2 + (cx + j0) * s, s // 2 + (cy + i0) * s, s))
        return seeds

    def _extract_from(self, image: np.ndarray, seed: tuple[int, int, int]) -> Detection:
        """The marker at or near ``seed`` (x, y, search radius px) on a cold try: scanned,
        and fitted whole if every scan refuses it."""
        det, refusal = self._scanned(image, seed, tracked=False)
        return det if refusal is None else self._fitted_whole_marker(image, refusal)

    def _fitted_whole_marker(self, image: np.ndarray, refusal: _Refusal) -> Detection:
        """A marker every scan refused on a cold try, fitted whole under a clipped highlight
        (``highlight.py``) or a cast shadow (``shadow.py``); else the scans' refusal, with
        why a fit that was tried was not taken."""
        p, det = self.params, refusal.det
        fits = ((p.highlight_model, "; fitted whole under a clipped highlight, refused: ",
                 highlight.UNTRIED,
                 lambda: self._highlighted(image, refusal.seed, refusal.prm, refusal.test)),
                (p.shadow_model, "; fitted whole under a cast shadow, refused: ", shadow.UNTRIED,
                 lambda: self._shadowed(image, refusal.first_v, refusal.prm, refusal.test)))
        for on, why_not, untried, attempt in fits:
            got = attempt() if on else untried[0]
            if isinstance(got, Detection):
                return got
            if got not in untried:
                return _miss(f"{det.reason}{why_not}{got}")
        return det

    def _scanned(self, image: np.ndarray, seed: tuple[int, int, int], tracked: bool
                 ) -> tuple[Detection, _Refusal | None]:
        """The marker at or near ``seed`` (x, y, search radius px), measured in one compiled
        call (``measure.measure``) and judged: a marker wider or taller than
        ``max_columns`` first on every k-th column and row (taken if found, cross-checked
        and judged so; else measured again on every one); a marker too small for the
        parameters is tried again with the small markers' ones, one whose edges a shadow's
        boundary may have moved with a narrower window, one whose lines failed under a
        clipped highlight from both scans' points at once (the first refusal stands when
        that fails too); with intrinsics, one short of edge points fitted as the
        deployment's rhombus. A marker the scans found is checked under a shadow
        (``_checked_under_shadow``); refused by that check, it comes without a refusal to
        fit whole (the fit disagreed with the scans). Any other cold refusal comes with
        what the whole-marker fits start from."""
        p = self.params
        lut, model = p.colour.lut, p.colour.vector
        test = self._shape if self._shape is not None and self._shape.size == (
            image.shape[1], image.shape[0]) else None  # intrinsics for this frame size
        if p.method == "paper":
            return self._paper(image, seed, tracked), None
        base, small = self._loose if test is not None else (self._prm, self._prm_small)
        prm = base
        measured = None
        if p.max_columns > 0:  # first a near marker's scans on every k-th column (and row)
            fast = base.copy()
            fast[measure.MAX_COLUMNS] = p.max_columns
            measured = measure.measure(image, *seed, lut, model, fast)
            if measured[1][measure.CAPPED] > 0:  # taken found and cross-checked, else again
                if measured[0] == measure.FOUND and measured[1][measure.CHECKED] > 0:
                    det, _ = self._judge(image, measured, fast, test, tracked)
                    if det.found and (checked := self._checked_under_shadow(image, det)).found:
                        return checked, None
                measured = None  # (on every column, as every later try)
        if measured is None:
            measured = measure.measure(image, *seed, lut, model, prm)
        first, first_v = measured[0], measured[2]
        if first in measure.FEW or first == measure.ROWS_OFF:  # a small marker?
            prm = small.copy()
            if measured[1][measure.AREA] < p.small_window_area_px:  # short chords: narrow
                prm[measure.WINDOW] = min(p.window, p.small_window)
            prm[measure.UNDER_HIGHLIGHT] = p.both_scans_under_highlight
            measured = measure.measure(image, *seed, lut, model, prm)
        det, biased = self._judge(image, measured, prm, test, tracked)
        if det.found:  # (refused by the check: not fitted whole again)
            return self._checked_under_shadow(image, det), None
        refused = int(measured[0])  # FOUND: refused by the profile or the shape test
        if biased and prm[measure.WINDOW] > p.narrow_window:
            narrow = self._narrow(prm)
            # a marker whose column scan alone was too uncertain needs the rows' agreement;
            # none is taken that the rows measured instead of the columns (checked only
            # against the columns' edge points: 7 of 37 such were more than 2 px off on 45 000
            # views of hard conditions)
            needs_rows = measured[1][measure.COLUMNS_UNSURE] > 0
            measured = measure.measure(image, *seed, lut, model, narrow)
            if measured[1][measure.ROWS_INSTEAD] == 0 and (
                    measured[1][measure.CHECKED] > 0 or not needs_rows):
                again, _ = self._judge(image, measured, narrow, test, tracked)
                if again.found:
                    return self._checked_under_shadow(image, again), None
        if p.both_scans_under_highlight and measure.fit_failed(first):
            # last: under a clipped highlight, both scans' points at once (a marker with too
            # few points had it on its second try)
            both = base.copy()
            both[measure.UNDER_HIGHLIGHT] = 1.0
            measured = measure.measure(image, *seed, lut, model, both)
            if measured[0] == measure.FOUND:
                again, _ = self._judge(image, measured, both, test, tracked)
                if again.found:
                    return self._checked_under_shadow(image, again), None
        if test is not None and p.shape_recovery and not tracked and \
                refused in measure.WANT_OF_POINTS:
            # (the scans with the first try's parameters: a small marker's second try
            # narrows the window for short chords, which the fit does not need)
            recovered = self._recover(image, seed, base, test)
            if recovered is not None:
                return recovered, None
        return det, (None if tracked else _Refusal(det, seed, first_v, base, test))

    def _highlighted(self, image: np.ndarray, seed: tuple[int, int, int], prm: np.ndarray,
                     test: ShapeTest | None) -> Detection | str:
        """The marker at ``seed`` the scans refused, fitted whole under a clipped highlight
        (``highlight.py``), if the fit is taken and passes the tests any detection passes;
        else why not (the scans' refusal stands)."""
        c = self.params.colour
        learned = self._learner.cameras(pp_spread=True) if self._learner is not None and \
            (self._learner.width, self._learner.height) == image.shape[1::-1] else []
        camera, model_m = (test.camera, test.marker_points) if test is not None else \
            (None, self._marker_m)
        fit = highlight.fit(image, seed[:2], c.lut, c.vector, c.green_bound, camera, model_m,
                            assumed=learned or None)
        return fit if isinstance(fit, str) else self._as_detection(image, fit, prm, test)

    def _shadowed(self, image: np.ndarray, v0: np.ndarray, prm: np.ndarray,
                  test: ShapeTest | None) -> Detection | str:
        """The marker the scans measured as v0 (4, 2) px and refused, fitted whole under a
        cast shadow (``shadow.py``), if the fit is taken and passes the tests any detection
        passes (the line fits' shape tests, the shape test with intrinsics, the uncertainty
        limit); else why not (the scans' refusal stands)."""
        fit = shadow.fit(image, v0, self.params.colour.lut)
        return fit if isinstance(fit, str) else self._as_detection(image, fit, prm, test)

    def _as_detection(self, image: np.ndarray, fit: shadow.ShadowFit | highlight.HighlightFit,
                      prm: np.ndarray, test: ShapeTest | None) -> Detection | str:
        """A marker fitted whole as a detection, if it passes the tests any detection passes
        (the line fits' shape tests, the shape test with intrinsics, the uncertainty limit);
        else why not."""
        H, W = image.shape[:2]
        v = fit.vertices_px
        if reason := _view_refusal(v, prm, W, H) or (
                test.refusal(v, fit.cov_px2) if test is not None else ""):
            return reason
        if (sigma := recover.largest_sigma_px(fit.cov_px2)) > self.params.max_vertex_sigma_px:
            return f"vertex uncertainty too large ({sigma:.2f} px, 1 sigma)"
        self._seed = _seed_around(v)
        area = recover.quad_area(v)
        return Detection(True, v, min(area / (W * H), 1.0), fit.residual_px, "", False, None,
                         fit.cov_px2)

    def _recover(self, image: np.ndarray, seed: tuple[int, int, int], prm: np.ndarray,
                 test: ShapeTest) -> Detection | None:
        """The marker at or near ``seed`` fitted as the deployment's rhombus to the edge
        points it shows (``recover.py``), if that passes the tests any detection passes (the
        line fits' shape tests, the shape test with intrinsics, the profile tests, the
        uncertainty limit); None otherwise (the line fits' refusal stands)."""
        p = self.params
        H, W = image.shape[:2]
        fit = recover.recover(image, seed, p.colour.lut, p.colour.vector, prm, test.camera,
                              test.marker_points, lambda v: _view_refusal(v, prm, W, H))
        if isinstance(fit, str) or test.refusal(fit.vertices_px, fit.cov_px2):
            return None
        v = fit.vertices_px
        # the profile across its edges, as a line fit's: an edge off its step, a vertex off
        # its edges' steps (a shadow's boundary) refuse; the rest adds to the uncertainty
        offsets, steps, edge, vertex, _ = profile.examine(
            image, v, p.colour.lut, p.colour.vector, p.max_step_offset_px,
            p.max_step_spread_px, p.max_vertex_step_px)
        if edge >= 0 or vertex >= 0:
            return None
        cov = fit.cov_px2 + covariance.profile_px2(offsets, steps)[:, None, None] * np.eye(2)
        if recover.largest_sigma_px(cov) > p.max_vertex_sigma_px:
            return None
        self._seed = _seed_around(v)
        area = recover.quad_area(v)
        return Detection(True, v, min(area / (W * H), 1.0), fit.rms_px, "", False, None, cov)

    def _narrow(self, prm: np.ndarray) -> np.ndarray:
        """The parameters ``prm`` of a second try with the narrow window (``narrow_window``),
        for a shadow's bias, not a highlight's gaps."""
        narrow = prm.copy()
        narrow[measure.WINDOW] = self.params.narrow_window
        narrow[measure.UNDER_HIGHLIGHT] = 0.0
        return narrow

    def _judge(self, image: np.ndarray, measured: tuple, prm: np.ndarray,
               test: ShapeTest | None, tracked: bool) -> tuple[Detection, bool]:
        """The detection from one measurement, after the shape and profile tests (the next
        frame's seed kept when found), and whether a refusal is one that a shadow's boundary
        inside the sub-pixel window can cause (``measure.BIASED``, an edge off its step)."""
        p = self.params
        status, stats, v, cov, u, d = measured
        if status != measure.FOUND:
            self._seed = None
            return _miss(_reason(status, stats, prm), tracked), status in measure.BIASED
        if test is not None and (reason := test.refusal(v, cov)):
            self._seed = None
            return _miss(reason, tracked), False
        offsets, steps, edge, vertex, deviation = profile.examine(
            image, v, p.colour.lut, p.colour.vector, p.max_step_offset_px,
            p.max_step_spread_px, p.max_vertex_step_px)  # (one call: both tests)
        if edge >= 0:
            self._seed = None
            return _miss(
                f"the {profile.EDGE_NAMES[edge]}"
                " edge is not a clean step: its profile crosses half way "
                f"{offsets[edge]:+.1f}"
                " px from the fitted line (a shadow's boundary along it?)", tracked), True
        if vertex >= 0:  # (not tried again: a narrower window leaves the vertex as far off)
            self._seed = None
            return _miss(
                f"the {profile.VERTEX_NAMES[vertex]}"
                " vertex is off its edges' steps: next to it an edge's profile crosses half way "
                f"{deviation:.1f}"
                " px off the others (a shadow's boundary near the vertex?)", tracked), False
        self._seed = (int(stats[measure.SEED_X]), int(stats[measure.SEED_Y]),
                      int(stats[measure.SEED_RADIUS]))
        det = Detection(True, v, float(stats[measure.AREA_RATIO]),
                        float(stats[measure.RESIDUAL]), "", tracked, (u, d),
                        covariance.reported(v, cov, offsets, steps))
        return self._checked_under_highlight(image, det, prm, test), False

    def _checked_under_shadow(self, image: np.ndarray, det: Detection) -> Detection:
        """A marker the scans found but are unsure of (a vertex's reported sigma over
        ``shadow.CHECK_SIGMA_PX``), or with the marker's colour just beyond an edge (over
        ``shadow.CHECK_BEYOND_SHARE``, ``profile.marker_beyond``: a shadow's boundary inside
        the marker taken for that edge), checked by the fit of the whole marker under a cast
        shadow started from its vertices: where that fit is taken and puts a vertex more than
        ``shadow.CHECK_APART_PX`` from theirs, refused (a shadow's boundary moved the scans'
        edges). Not fitted whole again: the fit's own vertices were the wrong ones where the
        scans were right. A fit not taken (no shadow) leaves the detection as it is."""
        v, cov = det.vertices_px, det.vertices_cov_px2
        if not (det.found and self.params.shadow_model and v is not None and cov is not None):
            return det
        limit, c = shadow.CHECK_SIGMA_PX, self.params.colour
        # (the trace bounds the larger eigenvalue: 2 µs, not eigvalsh's 22)
        sure = float((cov[:, 0, 0] + cov[:, 1, 1]).max()) <= limit * limit or \
            recover.largest_sigma_px(cov) <= limit
        if sure and profile.marker_beyond(image, v, c.lut, c.vector) \
                <= shadow.CHECK_BEYOND_SHARE:
            return det
        fit = shadow.fit(image, v, c.lut)
        if isinstance(fit, str):
            return det
        apart = np.linalg.norm(fit.vertices_px - v, axis=1)
        if apart[k := int(np.argmax(apart))] <= shadow.CHECK_APART_PX:
            return det
        self._seed = None
        return _miss(
            f"the scans put the {profile.VERTEX_NAMES[k]} vertex {apart[k]:.1f}"
            " px from where the marker fitted whole under a cast shadow does, their uncertainty "
            f"{recover.largest_sigma_px(cov):.2f}"
            " px (1 sigma): a shadow's boundary across the marker", det.tracked)

    def _checked_under_highlight(self, image: np.ndarray, det: Detection, prm: np.ndarray,
                                 test: ShapeTest | None) -> Detection:
        """A marker the scans found with clipped white near a vertex (within
        ``highlight.CHECK_NEAR_PX``), checked by the fit of the whole marker under the
        highlight started from its vertices: where the fit is taken and moves a vertex more
        than ``highlight.CHECK_APART_PX``, its vertices replace the scans' (a highlight's
        halo bent an edge's points; each vertex's covariance grown by
        ``highlight.CHECK_APART_SHARE`` of its move, in quadrature; ``residual_px`` then the
        fit's edge bands', as for the fallback fits, and no edge points), or the marker is
        refused: where the fit is unsure of any vertex (``highlight.CHECK_MAX_SIGMA_PX``), or
        where its grown covariance or its quadrilateral fails the tests any detection passes
        (a cold try then goes on to the fits from the blob's hull; a tracked one to the cold
        search, which checks the marker again). A fit not taken leaves the scans' detection
        as it is."""
        v = det.vertices_px
        assert v is not None
        if not self.params.highlight_model or not measure.white_near(
                image, v, highlight.CHECK_NEAR_PX, highlight.CLIPPED_LEVEL):
            return det
        c = self.params.colour
        centre = (int(v[:, 0].mean() + 0.5), int(v[:, 1].mean() + 0.5))
        fit = highlight.fit(image, centre, c.lut, c.vector, c.green_bound, start_px=v)
        if isinstance(fit, str):
            return det
        apart = np.linalg.norm(fit.vertices_px - v, axis=1)
        k = int(np.argmax(apart))
        if apart[k] <= highlight.CHECK_APART_PX:
            return det
        off = (f"the scans put the {profile.VERTEX_NAMES[k]} vertex {apart[k]:.1f} px from "
               "where the marker fitted whole under a clipped highlight does")
        if (sigma := recover.largest_sigma_px(fit.cov_px2)) > highlight.CHECK_MAX_SIGMA_PX:
            self._seed = None
            return _miss(f"{off}, and that fit is uncertain ({sigma:.2f} px, 1 sigma; at most "
                         f"{highlight.CHECK_MAX_SIGMA_PX} px): a vertex under the highlight",
                         det.tracked)
        # neither is the truth: each vertex's covariance grows by a share of how far the
        # scans put it (the fit's own understates it where they disagree)
        grown = fit.cov_px2 + (highlight.CHECK_APART_SHARE * apart)[:, None, None] ** 2 \
            * np.eye(2)
        fitted = self._as_detection(image, replace(fit, cov_px2=grown), prm, test)
        if isinstance(fitted, str):
            self._seed = None
            return _miss(f"{off}, and that fit is refused: {fitted}", det.tracked)
        return replace(fitted, tracked=det.tracked)

    def _paper(self, image: np.ndarray, seed: tuple[int, int, int], tracked: bool
               ) -> Detection:
        """Tables 1 and 2 as published (``paper.py``), judged by the same plausibility check
        (without the line residual, which the paper does not have)."""
        det = self._paper_from(image, seed, tracked)
        if det.found:
            assert det.vertices_px is not None
            self._seed = _seed_around(det.vertices_px)
        else:
            self._seed = None
        return det

    def _paper_from(self, image: np.ndarray, seed: tuple[int, int, int], tracked: bool
                    ) -> Detection:
        p = self.params
        H, W = image.shape[:2]
        sx, sy = scan.find_seed(image, seed[0], seed[1], seed[2], p.colour.lut,
                                p.colour.vector)
        if sx < 0:
            return _miss("no marker-coloured pixels at the seed", tracked)
        status, u, d = paper.table1(image, sx, sy, p.min_len_px, p.dx, p.colour.lut,
                                    p.colour.vector)
        if status == paper.BORDER:
            return _miss("marker touches the image border", tracked)
        if status == paper.TOO_SHORT or u.shape[0] < 2 * p.min_points_per_edge:
            return _miss(f"marker too small ({u.shape[0]} columns)", tracked)
        ok, v = paper.vertices(u, d)
        if not ok:
            return _miss("parallel edges: not a rhombus", tracked)
        verdict, quad_area, amin, amax = lines.check_rhombus(v, 0.0, 0.0, W, H,
                                                             self.min_angle_deg, np.inf)
        if verdict not in (lines.PLAUSIBLE, lines.AREA_MISMATCH):
            return _miss(_verdicts[verdict].format(residual=0.0, area=quad_area, blob=0,
                                                   amin=amin, amax=amax), tracked)
        if quad_area < p.min_area_px:
            return _miss(f"marker too small ({quad_area:.0f} px < {p.min_area_px:.0f} px)",
                         tracked)
        return Detection(True, v, min(quad_area / (W * H), 1.0), 0.0, "", tracked, (u, d))


#: The line fits' covariance treats edge points as independent; neighbouring columns share
#: pixels through the optics blur, the demosaicing and JPEG, so it is scaled (and floored by
#: the renderer-independent error of the edge model) to make the squared vertex errors
#: normalised by it average 2 on webcam renders (``tests/test_vertex_extractor.py``).
COV_SCALE = 5.0
COV_FLOOR_PX2 = 0.0004
#: the diagonals of the rhombus at depth Z cross at most h / 2Z off their midpoints (h its
#: longer half-diagonal); the depth at the image's corners is less than the distance: this
#: covers up to 42 degrees off the optical axis (1 / cos 42)
DIAGONAL_SHIFT_SLACK = 1.35
#: the sharpest corner the marker can show (``sharpest_corner_deg``) is allowed this much
#: sharper still: perspective at the nearest view and the fit's noise on a thin marker
CORNER_SLACK = 0.8


def sharpest_corner_deg(diagonal_ratio: float, off_normal_deg: float) -> float:
    """The sharpest corner (deg) of a rhombus whose diagonals' ratio is ``diagonal_ratio``,
    seen ``off_normal_deg`` off its normal about either diagonal (weak perspective): turned
    about its longer diagonal, the shorter one shrinks by the cosine."""
    short = min(diagonal_ratio, 1.0 / diagonal_ratio)
    return math.degrees(2.0 * math.atan(short * math.cos(math.radians(off_normal_deg))))


#: a marker whose horizontal diagonal is more than this share of its vertical one is a shape
#: that pink cards and sticky notes take in some view the shape tests allow (marker-less
#: frames with pink things, docs/measured.md "The marker's shape": none of 1 200 taken for the
#: default 0.76 marker, 1 of 200 at 0.86, 5 at 0.93, a sixth at 1.0 and a third at 1.17)
MAX_DISTINCT_RATIO = 0.85
#: a marker narrower than this has sharper top and bottom corners, whose vertices an edge's
#: shadow-bent line moves further (1 / sin of the half-angle): under a hard cast shadow more
#: than 1 % of views came out over 2 px off (seeds 31-35, 1 000 views, cold: 1.9 % at 0.61,
#: 1.5 % at 0.65, 1.2 % at 0.70, 0.9 % at the default 0.76, 0.3 % at 0.85; docs/measured.md
#: "On five more seeds, and with a narrower marker")
MIN_ROBUST_RATIO = 0.70


def shape_warning(diagonal_ratio: float) -> str:
    """Why a marker whose horizontal diagonal is ``diagonal_ratio`` times its vertical one
    will be confused with everyday magenta things, or measured wrong more often under cast
    shadows, or "" when its shape is neither."""
    if diagonal_ratio > MAX_DISTINCT_RATIO:
        return (f"the marker's diagonals (horizontal {diagonal_ratio:.2f} x the vertical) make "
                f"a shape that pink cards and sticky notes take in some views: they will be "
                f"taken for the marker when it is out of view (and make frames with it "
                f"ambiguous). Use a marker taller than wide, its horizontal diagonal at most "
                f"{MAX_DISTINCT_RATIO:.2f} x the vertical (the default: 5.0 x 6.6 cm)")
    if diagonal_ratio < MIN_ROBUST_RATIO:
        return (f"the marker's diagonals (horizontal {diagonal_ratio:.3f} x the vertical) make "
                f"its top and bottom corners sharp: a cast shadow across it moves those "
                f"vertices further, and more than 1 % of views under a hard cast shadow are "
                f"measured over 2 px off (at 0.61, twice the default marker's rate). Use a "
                f"horizontal diagonal of {MIN_ROBUST_RATIO:.2f}-{MAX_DISTINCT_RATIO:.2f} x the "
                f"vertical (the default: 5.0 x 6.6 cm)")
    return ""


#: the covariance of the mean of the column and the row scan's vertices: the scans' mean
#: covariance scaled (their errors are partly independent) plus the square of their
#: disagreement scaled; the shape test weighs the vertices by it, and ``covariance.reported``
#: makes it the one reported (``tests/test_hard_conditions.py``)
MEAN_COV_SCALE = 0.4
#: check the column scan against a row scan of the same marker (about twice the time; blur
#: and shadows bias one of them) and refuse a vertex disagreement beyond this (px)
CROSS_CHECK = True
MAX_SCAN_DISAGREEMENT_PX = 2.5
GAP_COV_SCALE = 0.5
#: a marker measured along its rows instead (its column lines failed) is refused where the
#: rows' lines are farther than this (px) from the column scan's measured edge points
#: (``measure.points_off``; ``ExtractorParams.check_rows_instead``)
MAX_ROWS_OFF_PX = 1.5


#: a cold search's detection refused under the camera learned from the marker, at its focal
#: length and both ends of its band (``RhombusExtractor._learned_refusal``)
LEARNED_SHAPE = "not the marker's rhombus under the camera learned from the marker: "


def _params_vector(p: ExtractorParams, diagonal_ratio: float, max_diagonal_shift: float,
                   min_angle_deg: float) -> np.ndarray:
    """The parameters as ``measure.measure`` takes them (its layout constants)."""
    prm = np.zeros(measure.N_PARAMS)
    prm[measure.MIN_LEN], prm[measure.DX], prm[measure.WINDOW] = p.min_len_px, p.dx, p.window
    prm[measure.EDGE], prm[measure.OUTER] = _EDGES[p.edge], p.outside_rows
    prm[measure.MIN_AREA], prm[measure.MIN_POINTS] = p.min_area_px, p.min_points_per_edge
    prm[measure.MAX_OUTSIDE_SHARE] = p.max_outside_share
    prm[measure.COV_SCALE], prm[measure.COV_FLOOR] = COV_SCALE, COV_FLOOR_PX2
    prm[measure.MIN_ANGLE], prm[measure.MAX_RESIDUAL] = min_angle_deg, p.max_residual_px
    prm[measure.DIAGONAL_RATIO] = diagonal_ratio
    prm[measure.MAX_OFF_NORMAL], prm[measure.MAX_ROLL] = p.max_off_normal_deg, p.max_roll_deg
    prm[measure.MAX_PITCH], prm[measure.MAX_SIGMA] = p.max_pitch_deg, p.max_vertex_sigma_px
    prm[measure.CROSS_CHECK], prm[measure.MAX_GAP] = CROSS_CHECK, MAX_SCAN_DISAGREEMENT_PX
    prm[measure.MEAN_COV_SCALE], prm[measure.GAP_COV_SCALE] = MEAN_COV_SCALE, GAP_COV_SCALE
    prm[measure.FUSE] = p.fuse_scans
    prm[measure.JOINT] = p.joint_fit
    prm[measure.MAX_OFF] = MAX_ROWS_OFF_PX if p.check_rows_instead else 0.0
    prm[measure.JOINT_ROWS] = p.joint_rows_instead
    prm[measure.SHADED_SPREAD] = p.shaded_spread
    prm[measure.SHADED_DEPTH] = p.shaded_inside_depth
    prm[measure.SHADED_GRADIENT] = p.shaded_gradient
    prm[measure.MAX_DIAGONAL_SHIFT] = max_diagonal_shift
    return prm  # (MAX_COLUMNS 0: every column; ``_scanned``'s first try sets it)


def _reason(status: int, s: np.ndarray, prm: np.ndarray) -> str:
    """A refusal's message from ``measure.measure``'s status and figures ``s``."""
    m = measure
    if status >= m.VERDICT and status < m.SHAPE:
        return _verdicts[status - m.VERDICT].format(
            residual=s[m.RESIDUAL], area=s[m.QUAD_AREA], blob=int(s[m.AREA]),
            amin=s[m.ANGLE_MIN], amax=s[m.ANGLE_MAX])
    if status >= m.FIT and status < m.VERDICT:
        return _fits[status - m.FIT]
    if status == m.SMALL_AREA:
        return f"marker too small ({int(s[m.AREA])} px < {prm[m.MIN_AREA]:.0f} px)"
    if status == m.FEW_COLUMNS:
        return f"marker too small ({int(s[m.COLUMNS])} usable columns)"
    if status == m.LOW_CONTRAST:
        return f"marker contrast too low ({s[m.CONTRAST]:.0f} grey levels)"
    if status == m.SHAPE:
        return (f"not the marker's shape in any expected view (as the marker it would be "
                f"{s[m.TILT]:.0f} deg off its normal, rolled {s[m.ROLL]:.0f} deg, "
                f"{s[m.PITCH]:.0f} deg about its horizontal axis)")
    if status == m.PERSPECTIVE:
        return (f"not the marker from the working distance: its diagonals cross "
                f"{100 * s[m.DIAGONAL_SHIFT]:.0f} % of their length off their midpoints "
                f"(at most {100 * prm[m.MAX_DIAGONAL_SHIFT]:.0f} % from nearest_view_m on; a "
                f"vertex cut off by something in front?)")
    if status == m.UNCERTAIN:
        return f"vertex uncertainty too large ({s[m.SIGMA]:.2f} px, 1 sigma)"
    if status == m.ROWS_OFF:
        return (f"the row scan's lines are {s[m.OFF]:.1f} px off the column scan's edge points "
                f"(a shadow's boundary along an edge?)")
    if status == m.DISAGREE:
        return (f"the column and row scans disagree by {s[m.GAP]:.1f} px (a shadow's "
                f"boundary along an edge, or blur)")
    return _refusals[status]


def _seed_around(v: np.ndarray) -> tuple[int, int, int]:
    """The next frame's seed (x, y, search radius px) at the vertices v (4, 2) px found by a
    route other than ``measure.measure`` (which returns its own)."""
    (x0, y0), (x1, y1), (x2, y2), (x3, y3) = v.tolist()  # plain floats: numpy's reductions
    xs, ys = (x0, x1, x2, x3), (y0, y1, y2, y3)  # cost more here
    radius = max(4, int(0.25 * min(max(xs) - min(xs), max(ys) - min(ys))))
    return int(sum(xs) / 4), int(sum(ys) / 4), radius


def _view_refusal(v: np.ndarray, prm: np.ndarray, width: int, height: int) -> str:
    """Why the quadrilateral v (4, 2) px is no view of the marker by the line fits' own shape
    tests (``measure._accept``: corner angles, the weak-perspective view, where the diagonals
    cross; the blob taken as the quadrilateral, no residual), "" when it may be one."""
    stats = np.zeros(measure.N_STATS)
    status = measure._accept(v, 0.0, np.zeros((4, 2, 2)), 0.0, recover.quad_area(v), width,
                             height, prm, stats, np.zeros((4, 2)), np.zeros((4, 2, 2)))
    return "" if status == measure.FOUND else _reason(status, stats, prm)


_refusals = {
    measure.NO_SEED: "no marker-coloured pixels at the seed",
    measure.BORDER: "the marker-coloured region reaches the image border (the marker cut by "
                    "it, or against a surround of its own colour)",
    measure.FEW_POINTS: "too few measurable edge points (shadowed, hidden or washed out)",
}
_fits = {
    lines.TOO_FEW_POINTS: "too few edge points on one side (partly hidden?)",
    lines.PARALLEL: "parallel edges: not a rhombus",
    lines.HIDDEN_EDGE: "an edge is mostly hidden or not straight (fewer than half its points "
                       "on one line)",
    lines.OUTSIDE_POINTS: "marker-coloured edge points outside the fitted quadrilateral (not "
                          "the whole marker)",
}
_verdicts = {
    lines.NOT_FINITE: "vertices not finite",
    lines.OUTSIDE: "the fitted edges meet outside the image (the marker cut by the border, or "
                   "an edge's points taken from something else: a highlight's halo, an arm)",
    lines.NOT_CONVEX: "the four lines do not make a convex quadrilateral",
    lines.BAD_ANGLES: "implausible corner angles ({amin:.0f} to {amax:.0f} deg)",
    lines.NOT_STRAIGHT: "edges are not straight (residual {residual:.2f} px): partly hidden?",
    lines.AREA_MISMATCH: "quadrilateral area {area:.0f} px does not match the blob's {blob} px "
                         "(partly hidden?)",
}


def read_only(image: np.ndarray) -> np.ndarray:
    """``image`` as a read-only view (itself when it is one already): the kernels are
    compiled once, for read-only frames (the service's, from the bus); a writeable frame
    handed to a kernel directly costs about a minute's compile of another variant at first."""
    if not image.flags.writeable:
        return image
    view = image.view()
    view.flags.writeable = False
    return view


def warm_up(params: ExtractorParams | None = None) -> None:
    """Compile (or load from numba's on-disk cache) the kernels, which take every frame
    read-only, so that the first real frame is not delayed (first run ever: about a minute;
    later: well under a second)."""
    image = np.zeros((120, 160, 3), np.uint8)
    rhombus = np.array([[30, 60], [80, 20], [130, 60], [80, 100]], np.int32)
    cv2.fillConvexPoly(image, rhombus, (200, 40, 200))
    for frame in (image, np.frombuffer(image.tobytes(), np.uint8).reshape(image.shape)):
        extractor = RhombusExtractor(params)
        extractor.extract(frame)  # cold
        extractor.extract(frame)  # tracked
    shape.warm_up()
    profile.warm_up()
    covariance.warm_up()
    recover.warm_up()
    quad_model.model(np.ones(quad_model.N_PARAMS), np.zeros(1), np.zeros(1), True)
