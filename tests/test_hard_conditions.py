"""The marker in a real room (issue 21): the simulator's hazards, and the extractor right or
refusing under each — shadows, an arm over an edge or a vertex, magenta things in view,
steep and small views — with an honest per-vertex uncertainty."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from services.core.camera import CameraModel
from services.core.mounts import Geometry
from services.sim import textures
from services.sim.hazards import Hazards, clipped_edge_share
from services.sim.render import RenderStyle, render_view
from services.sim.scenes import HARD_CONDITIONS, NO_MARKER, hard_views, marker_pose
from services.sim.webcam import WebcamParams
from services.vertex_extractor import measure, scan
from services.vertex_extractor.extractor import (
    Detection,
    ExtractorParams,
    RhombusExtractor,
    read_only,
    sharpest_corner_deg,
)
from services.vertex_extractor.lines import diagonal_shift

#: webcam-model frames kept as rendered (tests/data/hard_frames/README.md)
HARD_FRAMES = Path(__file__).parent / "data" / "hard_frames"


def _kept_frame(name: str) -> tuple[np.ndarray, np.ndarray]:
    """A frame kept in ``HARD_FRAMES`` and its true vertices (px, in the frame)."""
    image = cv2.imread(str(HARD_FRAMES / f"{name}.png"))
    assert image is not None, f"{HARD_FRAMES / name}.png is missing or unreadable"
    truth = json.loads((HARD_FRAMES / f"{name}.json").read_text())["vertices_px"]
    return read_only(image), np.array(truth)  # (as the kernels are compiled for)


def _assert_within(det: Detection, truth: np.ndarray, limit_px: float) -> None:
    """``det`` found, every vertex within ``limit_px`` of ``truth`` and 3 reported sigmas."""
    assert det.found and det.vertices_px is not None and det.vertices_cov_px2 is not None, \
        det.reason
    error = np.linalg.norm(det.vertices_px - truth, axis=1)
    sigma = np.sqrt(np.linalg.eigvalsh(det.vertices_cov_px2).max(axis=1))
    assert error.max() < limit_px and np.all(error < 3 * sigma), (error, sigma)


pytestmark = pytest.mark.skipif(not textures.have_photos(),
                                reason="scikit-image (dev extra) ships the photographs")


def _run(condition: str, n: int, seed: int = 3) -> tuple[list[np.ndarray], int, int, list]:
    """(per-frame vertex errors of the found ones, wrong (> 2 px), frames, detections)."""
    views = [v.rendered for v in hard_views(condition, n, seed=seed) if v.rendered.marker_visible]
    return _extract_all(views)


def _extract_all(views: list, params: ExtractorParams | None = None
                 ) -> tuple[list[np.ndarray], int, int, list]:
    """``_run`` on rendered views, each judged cold."""
    ex = RhombusExtractor(params)
    errors, wrong, dets = [], 0, []
    for r in views:
        ex.reset()
        det = ex.extract(r.image)
        assert det.found or det.reason  # every refusal says why
        if det.found and det.vertices_px is not None and r.vertices_px is not None:
            e = np.linalg.norm(det.vertices_px - r.vertices_px, axis=1)
            errors.append(e)
            wrong += bool(e.max() > 2.0)
            dets.append((det, r))
    return errors, wrong, len(views), dets


def _gains(views: list, off: ExtractorParams, more: int, what: str,
           on: ExtractorParams | None = None) -> None:
    """The views judged with a feature switched off (``off``) and on (``on``, by default the
    defaults): on, at least ``more`` more are found, and none more wrong. Both without the
    last resorts, the whole-marker fits (``shadow_model``, ``highlight_model``), which find
    much of what a scan's feature adds under a shadow or a highlight and would hide it."""
    counts = {}
    for name, params in (("off", off), ("on", on or ExtractorParams())):
        params = params.model_copy(update=dict(shadow_model=False, highlight_model=False))
        errors, wrong, _, _ = _extract_all(views, params)
        counts[name] = (len(errors), wrong)
    print(f"\n{what}: found, wrong without it {counts['off']}, with it {counts['on']}")
    assert counts["on"][0] >= counts["off"][0] + more, counts
    assert counts["on"][1] <= counts["off"][1], counts


def _style(**hazards: object) -> RenderStyle:
    return RenderStyle(seed=5, noise_sigma=0.0, photos=True, draw_body=False,
                       camera=WebcamParams(jpeg_quality=0), hazards=Hazards.model_validate(hazards))


def _view(style: RenderStyle, off_normal_deg: float = 10.0, distance_m: float = 0.3):
    cam, g = CameraModel.paper(), Geometry()
    T = marker_pose(distance_m, 320, 240, cam, np.radians(off_normal_deg))
    return render_view(cam, T, marker_points_m=g.marker_points(), style=style)


def test_every_hard_condition_renders_with_its_truth():
    for condition in [*HARD_CONDITIONS, NO_MARKER]:
        v = next(hard_views(condition, 1, seed=1))
        r = v.rendered
        assert r.image.shape == (480, 640, 3) and r.image.dtype == np.uint8
        assert (r.vertices_px is not None and r.marker_visible) == (condition != NO_MARKER)


def test_a_cast_shadow_darkens_one_side_and_an_occluder_reports_what_it_hides():
    lit = _view(_style())
    shadow = _view(_style(shadow_factor=0.35, shadow_angle_deg=0.0, shadow_offset=0.0))
    v = lit.vertices_px
    cx, cy = v.mean(0).astype(int)
    left = (slice(cy - 3, cy + 3), slice(cx - 12, cx - 6))
    right = (slice(cy - 3, cy + 3), slice(cx + 6, cx + 12))
    assert shadow.image[left].mean() > 0.8 * lit.image[left].mean()      # the lit side
    assert shadow.image[right].mean() < 0.8 * lit.image[right].mean()    # in the shadow
    arm = _view(_style(occluder="limb", occluder_from=(2.0, 0.0), occluder_to=(0.6, 0.0),
                       occluder_width=0.3))
    assert 0.03 < arm.occluded_fraction < 0.2
    sheared = _view(_style(rolling_shutter_px=30.0))
    # the truth moves with the frame: x + 30 y / (H - 1)
    assert np.allclose(sheared.vertices_px[:, 0] - lit.vertices_px[:, 0],
                       30.0 * lit.vertices_px[:, 1] / 479, atol=1e-9)


def test_the_other_rhombus_is_never_the_markers_shape():
    """The distractors' rhombus is another shape than the deployment's marker: 1.0-1.6 times
    as wide as tall beside the default (0.76) or a tall marker, wider still beside a square or
    a wide one (a square marker took it for itself on 15 of 600 views)."""
    from services.sim.hazards import OTHER_RHOMBUS, _distractor_shape

    def ratios(marker_ratio: float) -> np.ndarray:
        rng = np.random.default_rng(0)
        out = []
        for _ in range(200):
            quad = _distractor_shape("rhombus", rng, marker_ratio)[0]  # L T R B, turned
            out.append(np.hypot(*(quad[2] - quad[0])) / np.hypot(*(quad[3] - quad[1])))
        return np.array(out)
    default = Geometry()
    for marker_ratio in (default.marker_width_m / default.marker_height_m, 0.6):
        r = ratios(marker_ratio)
        assert r.min() >= 1.0 - 1e-9 and r.max() <= 1.6 + 1e-9
        assert r.min() >= 1.3 * marker_ratio - 1e-9
    for marker_ratio in (1.0, 1.3):
        r = ratios(marker_ratio)
        assert r.min() >= OTHER_RHOMBUS[0] * marker_ratio - 1e-9
        assert r.max() <= OTHER_RHOMBUS[1] * marker_ratio + 1e-9


def test_distractors_are_drawn_in_magenta_away_from_the_marker():
    from services.vertex_extractor.colour import ColourModel
    r = _view(_style(distractors=("card", "shirt", "cup", "rhombus"), distractor_seed=3))
    mask = ColourModel().mask(r.image)
    v = r.vertices_px
    x0, y0 = (v.min(0) - 14).astype(int)
    x1, y1 = (v.max(0) + 14).astype(int)
    outside = mask.copy()
    outside[max(y0, 0):y1, max(x0, 0):x1] = False
    assert outside.sum() > 500  # marker-coloured things elsewhere in the frame


def test_hard_shadow_moves_no_edge():
    errors, wrong, total, _ = _run("hard cast shadow (x0.35)", 24)
    assert wrong <= 1, f"{wrong} of {total} wrong"
    assert len(errors) >= 0.7 * total
    assert np.median(np.concatenate(errors)) < 0.4  # one inside level: 2-3 px


def test_an_arm_over_a_vertex_is_never_fitted_and_the_vertex_comes_from_the_lines():
    errors, wrong, total, dets = _run("limb or bar over one vertex", 24)
    assert wrong == 0, f"{wrong} of {total} wrong"
    assert len(errors) >= 0.5 * total
    hidden = [r.occluded_fraction for _, r in dets]
    assert max(hidden) > 0.02  # found with a part really hidden
    _within_reported(dets)


def test_a_tall_markers_rows_measure_it_where_an_arm_bends_its_column_lines():
    """A tall marker whose column lines do not fit it (not straight, an edge hidden, points
    beyond it: an arm over a vertex bends them) is measured along its rows, judged by the
    same tests: 3 of these 60 views were refused so; now 1, none wrong."""
    found = total = 0
    for seed in (2024, 7):
        errors, wrong, n, dets = _run("limb or bar over one vertex", 30, seed=seed)
        assert wrong == 0, (seed, wrong)
        _within_reported(dets)
        found, total = found + len(errors), total + n
    assert found >= total - 1, (found, total)


def _within_reported(dets: list) -> None:
    """Never confidently wrong: each vertex within 2 px or 3 of its reported sigmas."""
    for det, r in dets:
        sigma = np.sqrt(np.linalg.eigvalsh(det.vertices_cov_px2).max(1))
        e = np.linalg.norm(det.vertices_px - r.vertices_px, axis=1)
        assert np.all(e <= np.maximum(2.0, 3.0 * sigma)), (e, sigma)


def test_an_arm_across_an_edge_is_found_from_the_visible_lines_never_wrong():
    errors, wrong, total, dets = _run("limb or bar over one edge", 24)
    assert wrong == 0, f"{wrong} of {total} wrong"
    assert len(errors) >= 0.75 * total, (len(errors), total)  # the notch left out: was 40 %
    _within_reported(dets)


def test_a_notch_in_the_outline_is_left_out_but_an_outlier_outward_is_not_a_notch():
    from services.vertex_extractor import lines
    x = np.arange(40.0)
    y = 0.6 * np.abs(x - 20.0)  # the U points: the top vertex at x = 20 (y grows down)
    notched = y.copy()
    notched[6:13] += 6.0  # an arm across the upper-left edge
    keep = lines.on_hull(np.c_[x, notched], True, lines.HULL_TOLERANCE_PX)
    assert not keep[6:13].any() and keep[:5].all() and keep[15:].all()
    spiked = y.copy()
    spiked[3] -= 2.5  # one point far outward: the hull bridges from it, but that is no notch
    assert lines.on_hull(np.c_[x, spiked], True, lines.HULL_TOLERANCE_PX).all()
    lower = -notched  # the same for the D points (outward: larger y)
    assert not lines.on_hull(np.c_[x, lower], False, lines.HULL_TOLERANCE_PX)[6:13].any()
    # a notch with clipped white just outward of it is a highlight: nothing is left out
    from services.vertex_extractor import scan
    pts = np.c_[x, notched + 20.0]
    keep = lines.on_hull(pts, True, lines.HULL_TOLERANCE_PX)
    frame = np.full((60, 40, 3), 90, np.uint8)
    assert np.array_equal(scan.notch_kept(read_only(frame), pts, keep, -1), keep)
    frame[27:34, 6:13] = 255  # just above the notch points (rows 31-34)
    assert scan.notch_kept(read_only(frame), pts, keep, -1).all()


def test_magenta_things_in_view_are_never_taken_for_the_marker():
    """Nor with intrinsics, where the deployment's rhombus is also fitted to the edge points
    of what the line fits refuse (``recover.py``)."""
    errors, wrong, total, _ = _run("pink and magenta things in view", 12)
    assert wrong == 0 and len(errors) >= 0.9 * total
    ex, shaped = RhombusExtractor(), RhombusExtractor()
    shaped.use_intrinsics(CameraModel.paper())
    for v in hard_views(NO_MARKER, 30, seed=8):
        for e in (ex, shaped):
            e.reset()
            det = e.extract(v.rendered.image)
            assert not det.found, det.vertices_px


def test_a_card_in_the_markers_own_ink_is_refused_for_its_shape():
    """A tilted rectangle, and a square rhombus, printed in the marker's ink: four good
    corners, straight edges, but no view of the deployment's rhombus."""
    img = np.full((480, 640, 3), 120, np.uint8)
    ex = RhombusExtractor()
    for angle in (20.0, 35.0, 55.0, 70.0):
        card = cv2.boxPoints(((320.0, 240.0), (170.0, 108.0), angle))
        frame = img.copy()
        cv2.fillConvexPoly(frame, np.round(card * 16).astype(np.int32), (255, 0, 255),
                           cv2.LINE_AA, 4)
        det = ex.extract(frame)
        assert not det.found, angle
        ex.reset()
    square = np.array([[260, 240], [320, 180], [380, 240], [320, 300]], np.float32)
    frame = img.copy()
    cv2.fillConvexPoly(frame, np.round(square * 16).astype(np.int32), (255, 0, 255),
                       cv2.LINE_AA, 4)
    det = ex.extract(frame)
    assert not det.found and "not the marker's shape" in det.reason


def test_a_bigger_thing_of_the_markers_shape_beside_it_makes_the_frame_ambiguous():
    """A rhombus of the marker's shape in its ink, 2.5 times its size, beside the marker: which
    is the marker no shape test can tell (a square marker and a square card, a card turned to
    look like a wide marker), so the frame is refused as ambiguous; the bigger one was taken
    before, its smaller rival never tried. Alone, the marker is found."""
    cam, g = CameraModel.paper(), Geometry()
    T = marker_pose(0.6, 180, 240, cam, np.radians(10.0))
    r = render_view(cam, T, marker_points_m=g.marker_points(), style=_style())
    assert r.vertices_px is not None
    ex = RhombusExtractor()
    assert ex.extract(r.image).found
    ink = r.image[int(r.vertices_px[:, 1].mean()), int(r.vertices_px[:, 0].mean())]
    bigger = (r.vertices_px - r.vertices_px.mean(0)) * 2.5 + (450.0, 240.0)
    frame = r.image.copy()
    cv2.fillConvexPoly(frame, np.round(bigger * 16).astype(np.int32),
                       tuple(int(c) for c in ink), cv2.LINE_AA, 4)
    ex.reset()
    det = ex.extract(frame)
    assert not det.found and "ambiguous" in det.reason, det.vertices_px


def test_the_diagonals_cross_off_their_midpoints_by_the_depth_difference():
    """lines.diagonal_shift: the rhombus at depth Z turned by a about its vertical axis (its
    horizontal half-diagonal w: its ends at Z -/+ w sin a) crosses w sin a / 2Z off the
    horizontal diagonal's midpoint, exactly (and h sin a / 2Z off the vertical one's, turned
    about its horizontal axis); the default bound holds every view from 15 cm."""
    cam, g = CameraModel.paper(), Geometry()
    w = g.marker_width_m / 2
    h = g.marker_height_m / 2  # turned about its horizontal axis: the vertical diagonal
    for z, a in ((0.15, 70.0), (0.3, 40.0), (0.8, 10.0)):
        for azimuth, half in ((0.0, w), (np.pi / 2, h)):
            T = marker_pose(z, cam.K[0, 2], cam.K[1, 2], cam, np.radians(a), azimuth)
            v = cam.project((T[:3, :3] @ g.marker_points().T).T + T[:3, 3])
            expected = half * np.sin(np.radians(a)) / (2 * z)
            assert diagonal_shift(v) == pytest.approx(expected, rel=1e-9), (z, a, azimuth)
    bound = RhombusExtractor().max_diagonal_shift  # from 15 cm on (nearest_view_m)
    assert max(w, h) / (2 * 0.15) < bound < 0.2  # (turned about any axis, on the axis)
    big = Geometry(marker_width_m=0.1, marker_height_m=0.132)
    assert RhombusExtractor(geometry=big).max_diagonal_shift == pytest.approx(2 * bound)


def test_an_arms_edge_across_a_vertex_is_refused_by_where_the_diagonals_cross():
    """A webcam frame (tests/data/hard_frames) where a bar cuts the top vertex off along a
    straight edge: the column lines took the bar's edge for the marker's, every other test
    passed and the top vertex came out 20 px off at a reported 0.6 px. The diagonals cross
    21 % of their length off their midpoints, which no view from 15 cm gives (at most 11 %):
    that quadrilateral is refused, and the points again without the bar's notch in the
    outline give the marker."""
    img, truth = _kept_frame("arm_over_a_vertex")
    off = RhombusExtractor(ExtractorParams(nearest_view_m=0.01)).extract(img)  # (no bound)
    assert off.found and np.linalg.norm(off.vertices_px - truth, axis=1).max() > 10
    _assert_within(RhombusExtractor().extract(img), truth, 0.5)


def test_a_narrow_second_try_takes_nothing_from_the_rows_alone():
    """A webcam frame (tests/data/hard_frames) with a hard shadow's boundary along the upper
    right edge: refused (that edge is not one clean step), and tried again with the narrow
    window, whose column lines fail; the rows measured instead came out 4.6 px off at a
    reported 0.9 px, close to the columns' measured edge points (0.6 px) and not
    cross-checked. The narrow try takes no marker measured along the rows instead (7 of 37
    such were more than 2 px off on 45 000 hard-condition views): the first refusal stands."""
    img, truth = _kept_frame("shadow_rows_on_the_narrow_try")
    ex = RhombusExtractor()
    det = ex.extract(img)
    assert not det.found and "edge is not a clean step" in det.reason, det.reason
    narrow = ex._narrow(ex._prm)  # the narrow try's own measurement
    cx, cy = (int(c) for c in truth.mean(axis=0))
    status, stats, v, _, _, _ = measure.measure(img, cx, cy, 8, ex.params.colour.lut,
                                                ex.params.colour.vector, narrow)
    assert status == measure.FOUND and stats[measure.ROWS_INSTEAD] == 1.0
    assert np.linalg.norm(v - truth, axis=1).max() > 2.0


def test_the_row_scan_is_not_cut_off_at_the_column_scans_box():
    """A webcam frame (tests/data/hard_frames) under a clipped highlight: the column walk
    stops at the clipped core, 48 px above where the row walk, going round the core, ends.
    The rows were scanned on a region 44 px around the column scan's box, whose side they
    reached and which stopped them as the image's border would: the marker was refused
    ("quadrilateral area ... does not match the blob's"). Scanned on the whole image, the
    rows find it, within its reported uncertainty."""
    img, truth = _kept_frame("highlight_240")
    ex = RhombusExtractor()
    lut, model = ex.params.colour.lut, ex.params.colour.vector
    x, y, radius = ex._coarse_search(img)[0]
    sx, sy = scan.find_seed(img, x, y, radius, lut, model)
    prm = ex._prm
    status, *_, box = measure.column_scan(img, sx, sy, lut, model, prm)
    margin = 44  # the region's: 3 (window + outer) + 2 LOCAL_ROWS + 2 px
    x0, y0 = max(box[0] - margin, 0), max(box[2] - margin, 0)
    region = img[y0:box[3] + margin + 1, x0:box[1] + margin + 1].transpose(1, 0, 2)
    in_region = scan.scan(
        region, sy - y0, sx - x0, int(prm[measure.MIN_LEN]), int(prm[measure.DX]),
        int(prm[measure.WINDOW]), lut, model, int(prm[measure.EDGE]),
        int(prm[measure.OUTER]), prm[measure.SHADED_SPREAD], int(prm[measure.SHADED_DEPTH]),
        prm[measure.SHADED_GRADIENT] > 0, int(prm[measure.MAX_COLUMNS]))  # (as compiled)
    rows = measure._row_scan(img, sx, sy, lut, model, prm)
    assert status == scan.OK and in_region[0] == scan.BORDER and rows[0] == scan.OK
    _assert_within(ex.extract(img), truth, 1.0)


def test_under_a_highlight_the_joint_fit_starts_from_both_walks():
    """A webcam frame (tests/data/hard_frames) whose highlight splits the marker's blob in
    two. From the lower blob's seed the column walk covers the ink below the clipped core
    (from x = 57 px), the row walk goes round the core to the left vertex (from x = 47 px;
    the vertex is at 40.6). Both scans' lines fail, and both scans' points are fitted at
    once from a first quadrilateral on the box's sides and with the box's clipped pixels
    counted as the blob's: with the column walk's box that was refused ("the fitted edges
    meet outside the image"); with the box of both walks the marker is found, within its
    reported uncertainty. (Clipped white lies near its vertices, so the highlight's fit then
    checks it: it moves the left vertex by 1.2 px, to 1.2 px off, and that vertex's reported
    uncertainty grows to cover the move.)"""
    img, truth = _kept_frame("highlight_7_157")
    with pytest.MonkeyPatch.context() as m:  # (the joint fit alone, unchecked)
        m.setattr(measure, "white_near", lambda *_: False)
        _assert_within(RhombusExtractor().extract(img), truth, 1.0)
    ex = RhombusExtractor()
    lut, model = ex.params.colour.lut, ex.params.colour.vector
    x, y, radius = ex._coarse_search(img)[1]  # (the lower blob)
    sx, sy = scan.find_seed(img, x, y, radius, lut, model)
    *_, box = measure.column_scan(img, sx, sy, lut, model, ex._prm_small)
    row_box = measure._row_scan(img, sx, sy, lut, model, ex._prm_small)[7]
    assert row_box[0] < box[0] - 5  # (x0, x1, y0, y1)
    _assert_within(ex.extract(img), truth, 1.5)


def test_steep_and_small_markers_are_found():
    for condition in ("steep: 55-70 deg", "small: 25-40 px across"):
        errors, wrong, total, _ = _run(condition, 20)
        assert wrong <= 1 and len(errors) >= 0.75 * total, (condition, wrong, len(errors), total)


def test_a_lens_with_barrel_distortion_bends_no_vertex_off():
    """The clean condition through the paper's camera with k1 = -0.25 (a cheap wide webcam's
    barrel: the frame's corners 16-45 px inward, the edges of a marker there bowed):
    without intrinsics (nothing learned from such views: no pinhole fits them) and with the
    lens's, found on nearly every view, none more than 2 px off."""
    from services.tools.bench.vertices import BARREL_K1
    paper = CameraModel.paper()
    lens = CameraModel(paper.K, np.array([BARREL_K1, 0.0, 0.0, 0.0, 0.0]), 640, 480)
    views = [v.rendered for v in hard_views("clean", 60, seed=3, camera=lens)
             if v.rendered.marker_visible]
    corner = np.linalg.inv(paper.K) @ np.array([0.0, 0.0, 1.0])  # (the top left pixel's ray)
    assert np.hypot(*lens.project(corner[None, :])[0]) > 40.0  # (the lens bends it in)
    errors, wrong, total, _ = _extract_all(views)
    assert wrong == 0 and len(errors) >= 0.95 * total, (wrong, len(errors), total)
    assert np.median(np.concatenate(errors)) < 0.2


def test_steep_views_are_found_through_glancing_columns_and_sharp_vertices():
    """55-70 deg off the normal the marker is tall and narrow: its columns cross the near-
    vertical edges at a glancing angle (their lines met off the image: "a vertex falls
    outside"), and next to its sharp vertices the profile's inside level fell on the surround
    (the vertex test refused clean views). 7 of these 75 views were refused so; now none."""
    errors, wrong, total, _ = _run("steep: 55-70 deg", 75, seed=11)
    assert wrong == 0 and len(errors) >= total - 1, (wrong, len(errors), total)


def test_the_corner_limit_follows_the_deployments_marker():
    """The sharpest plausible corner comes from the marker's own shape: 2 atan(short / long
    diagonal x cos(max_off_normal_deg)), x 0.8 for perspective. A fixed 25 deg refused a tall
    6 x 10 cm marker seen 68-70 deg off its normal ("implausible corner angles"): its own
    limit finds those views, and takes nothing from marker-less frames of pink things."""
    assert sharpest_corner_deg(1.0, 0.0) == pytest.approx(90.0)
    assert sharpest_corner_deg(0.6, 60.0) == pytest.approx(sharpest_corner_deg(1 / 0.6, 60.0))
    assert sharpest_corner_deg(0.6, 60.0) == pytest.approx(np.degrees(2 * np.arctan(0.3)))
    assert RhombusExtractor().min_angle_deg == pytest.approx(17.7, abs=0.1)
    assert RhombusExtractor(ExtractorParams(min_angle_deg=25.0)).min_angle_deg == 25.0
    tall = Geometry(marker_width_m=0.06, marker_height_m=0.10)
    fixed = RhombusExtractor(ExtractorParams(min_angle_deg=25.0), geometry=tall)
    own = RhombusExtractor(geometry=tall)
    assert own.min_angle_deg == pytest.approx(14.1, abs=0.1)
    views = [v.rendered for v in hard_views("steep: 55-70 deg", 60, seed=31, geometry=tall)]
    views = [r for r in views if r.marker_visible and r.vertices_px is not None]
    refused_for_angles = 0
    for r in views:
        fixed.reset()
        before = fixed.extract(r.image)
        if before.found or "corner angles" not in before.reason:
            continue
        refused_for_angles += 1
        own.reset()
        det = own.extract(r.image)
        assert det.found, det.reason
        assert np.linalg.norm(det.vertices_px - r.vertices_px, axis=1).max() < 2.0  # not wrong
    assert refused_for_angles >= 2, refused_for_angles  # (3 of these 60)
    for v in hard_views(NO_MARKER, 40, seed=5, geometry=tall):
        own.reset()
        assert not own.extract(v.rendered.image).found


def test_a_small_markers_second_try_reads_its_short_chords_with_a_narrow_window():
    """25-40 px across, a marker's chords near its vertices are 8-12 px long: a 5 px window
    each side (and the inside level beyond it) leaves too few of their points measurable. Its
    second try reads them with a 3 px window (blobs under 800 px²): on these 150 views the
    5 px one found 141, one of them wrong; now 145, none wrong."""
    found = wrong = total = 0
    for seed in (5, 23):
        errors, w, t, _ = _run("small: 25-40 px across", 75, seed=seed)
        found, wrong, total = found + len(errors), wrong + w, total + t
    assert wrong == 0 and found >= total - 5, (wrong, found, total)


@pytest.mark.slow  # many renders
def test_a_shadowed_markers_second_try_reads_its_edges_with_a_narrow_window():
    """A cast shadow's boundary a few px inside an edge falls in the 5 px window of one scan
    and moves that edge: the column and row scans disagree, or the vertices come out too
    uncertain, and the marker was refused. Tried again with a 3 px window (the same tests),
    more of them are found, and none wrong: on 900 views a condition, hard shadows 91.1 ->
    94 %, soft 94 -> 95 % found (docs/measured.md)."""
    shadows = ("hard cast shadow (x0.35)", "soft cast shadow (x0.35, 8-40 px)")
    # (4 more found of 120 views each; of 80, 3, then 2 once robust_split's ties went to
    # the lines' crossing: one view refused as too uncertain, 1.36 px)
    views = [v.rendered for c in shadows for v in hard_views(c, 120, seed=5)
             if v.rendered.marker_visible]
    off = ExtractorParams(narrow_window=ExtractorParams().window)  # no second try
    _gains(views, off, 3, "the narrow second try")


def test_a_shaded_markers_edges_take_their_local_inside_level():
    """Under a cast shadow the whole chain's mean inside level is off wherever the light
    differs from it (a soft shadow's gradient, a hard one's step): each edge point of a
    shaded marker (``shaded_spread``: its columns' centres spread by more than 20 %) takes
    its local level. On these 150 shadowed views the median vertex error drops by a tenth or
    more, found and wrong no worse (1 500 views: soft shadow 0.23 -> 0.20 px, wrong 13 -> 9;
    hard 0.16 -> 0.13 px, 11 -> 9; docs/measured.md); a clean marker is not shaded."""
    views = [v.rendered for c in ("soft cast shadow (x0.35, 8-40 px)", "hard cast shadow (x0.35)")
             for v in hard_views(c, 75, seed=5) if v.rendered.marker_visible]
    runs = {}
    for name, params in (("off", ExtractorParams(shaded_spread=1.0)), ("on", None)):
        errors, wrong, _, _ = _extract_all(views, params)
        runs[name] = (len(errors), wrong, float(np.median(np.concatenate(errors))))
    print(f"\nshaded: found, wrong, median px off {runs['off']}, on {runs['on']}")
    assert runs["on"][2] < 0.9 * runs["off"][2], runs
    assert runs["on"][0] >= runs["off"][0] and runs["on"][1] <= runs["off"][1], runs
    even = _view(_style())  # in even light the chain's mean level, as before
    off = RhombusExtractor(ExtractorParams(shaded_spread=1.0)).extract(even.image)
    assert np.array_equal(RhombusExtractor().extract(even.image).vertices_px, off.vertices_px)


@pytest.mark.slow  # many renders
def test_a_shaded_markers_inside_level_is_read_nearer_its_sharp_edges():
    """A shaded marker's local inside level, read just beyond the 5 px window (6-8 px inside
    each run's end), often lies across the shadow's boundary or down its gradient from the
    edge; read 4 px in (``shaded_inside_depth``) it does so less often. On these 400
    shadowed views more are found and none more wrong (6 000 views each: hard shadow 65 -> 50
    wrong, soft 44 -> 40; docs/measured.md). Where blur's ramp reaches that deep
    (``scan._sharpness``) the level is read beyond the window still: a shadowed marker
    defocused by 4 px is measured exactly as without it."""
    views = [v.rendered for seed in (5, 6)
             for c in ("soft cast shadow (x0.35, 8-40 px)", "hard cast shadow (x0.35)")
             for v in hard_views(c, 100, seed=seed) if v.rendered.marker_visible]
    off = ExtractorParams(shaded_inside_depth=0, shaded_gradient=False)
    _gains(views, off, 4, "the shaded inside level nearer the edge",
           on=ExtractorParams(shaded_gradient=False))  # (the gradient: the test below)
    shadow = {"shadow_factor": 0.35, "shadow_softness_px": 20.0, "shadow_angle_deg": 30.0,
              "shadow_offset": 0.2}
    for defocus_px, changed in ((0.0, True), (4.0, False)):
        image = _view(_style(**shadow, defocus_px=defocus_px)).image
        on_v = RhombusExtractor().extract(image).vertices_px
        off_v = RhombusExtractor(off).extract(image).vertices_px
        assert on_v is not None and off_v is not None
        assert (not np.array_equal(on_v, off_v)) == changed, defocus_px


@pytest.mark.slow  # many renders
def test_a_soft_shadows_gradient_across_an_edge_is_followed():
    """Where a shaded marker's inside level is read nearer its edges, a soft shadow's
    penumbra still changes the light between that level and the edge, and the coverage sum
    moves the edge by the change times the window. Each row's coverage is now taken against
    the level carried there along the light's steady change (``shaded_gradient``): on these
    200 soft-shadowed views the median vertex error drops by more than 10 % (900 views: 0.19
    -> 0.17 px, docs/measured.md), none more wrong, found within 2 %; under a hard
    shadow (its boundary a step, not a gradient) found and wrong are as without it."""
    off = ExtractorParams(shaded_gradient=False)
    for condition, soft in (("soft cast shadow (x0.35, 8-40 px)", True),
                            ("hard cast shadow (x0.35)", False)):
        views = [v.rendered for seed in (5, 6) for v in hard_views(condition, 100, seed=seed)
                 if v.rendered.marker_visible]
        runs = {}
        for name, params in (("off", off), ("on", None)):
            errors, wrong, _, _ = _extract_all(views, params)
            runs[name] = (len(errors), wrong, float(np.median(np.concatenate(errors))))
        print(f"\n{condition}: found, wrong, median px off {runs['off']}, on {runs['on']}")
        assert runs["on"][1] <= runs["off"][1], runs
        assert runs["on"][0] >= runs["off"][0] - 5, runs
        if soft:
            assert runs["on"][2] < 0.9 * runs["off"][2], runs
        else:
            assert abs(runs["on"][2] - runs["off"][2]) < 0.02, runs


def test_the_lights_gradient_is_taken_only_where_it_changes_steadily():
    """``scan._gradient``: the inside level's change per row from two deeper bands, where
    both steps go the same way and alike (a soft shadow's penumbra); not across a hard
    shadow's boundary (one step), nor where the change is within the JPEG's noise."""
    from services.vertex_extractor import scan
    w = np.array([0.0, 0.0, 1.0])  # the score: the red channel
    gap = scan.GRADIENT_GAP

    def bands(mid: float, far: float) -> np.ndarray:
        return np.array([[0.0, 0.0, mid], [0.0, 0.0, far]])

    assert scan._gradient(w, bands(90.0, 80.0), 100.0, 100.0) == pytest.approx(-20.0 / (2 * gap))
    assert scan._gradient(w, bands(110.0, 121.0), 100.0, 100.0) == pytest.approx(21.0 / (2 * gap))
    assert scan._gradient(w, bands(60.0, 60.0), 100.0, 100.0) == 0.0  # a step between bands
    assert scan._gradient(w, bands(95.0, 60.0), 100.0, 100.0) == 0.0  # not alike
    assert scan._gradient(w, bands(90.0, 95.0), 100.0, 100.0) == 0.0  # down, then up
    assert scan._gradient(w, bands(99.0, 98.0), 100.0, 100.0) == 0.0  # within the noise
    assert scan._gradient(w, bands(70.0, 40.0), 100.0, 100.0) == 0.0  # more than half: no gradient
    # on a render: a sharp marker across a soft shadow's penumbra is measured otherwise; one
    # in even light, one defocused, and any with the setting off, exactly as before
    off = ExtractorParams(shaded_gradient=False)
    penumbra = {"shadow_factor": 0.35, "shadow_softness_px": 30.0, "shadow_angle_deg": 30.0,
                "shadow_offset": 0.2}
    for hazards, changed in ((penumbra, True), ({}, False),
                             ({**penumbra, "defocus_px": 4.0}, False)):
        image = _view(_style(**hazards), distance_m=0.25).image
        on_v = RhombusExtractor().extract(image).vertices_px
        off_v = RhombusExtractor(off).extract(image).vertices_px
        assert on_v is not None and off_v is not None
        assert (not np.array_equal(on_v, off_v)) == changed, hazards


def test_an_uncertain_column_scan_takes_the_row_scans_better_vertex():
    """measure.fuse: each vertex the scans' mean weighted by the inverse of each one's
    variance; a vertex the columns hardly know (a highlight over it) comes from the rows,
    with the rows' uncertainty; equal uncertainties give cross_check's mean."""
    from services.vertex_extractor import extractor, measure
    v = np.array([[10.0, 50.0], [40.0, 10.0], [70.0, 50.0], [40.0, 90.0]])
    cov = np.tile(0.04 * np.eye(2), (4, 1, 1))
    unsure = cov.copy()
    unsure[1] = 4.0 * np.eye(2)  # the top vertex: sigma 2 px along the columns
    rows = v + np.array([0.0, 1.0])
    fused, fused_cov = v.copy(), unsure.copy()
    gap, sigma = measure.fuse(fused, fused_cov, rows, cov, extractor.MEAN_COV_SCALE,
                              extractor.GAP_COV_SCALE)
    assert gap == 1.0
    assert abs(fused[1, 1] - rows[1, 1]) < 0.02  # the top vertex: the rows' (weight 0.99)
    assert np.allclose(fused[[0, 2, 3]], v[[0, 2, 3]] + np.array([0.0, 0.5]))  # the mean
    grown = extractor.GAP_COV_SCALE * gap ** 2  # the disagreement's share, as cross_check's
    assert fused_cov[1, 0, 0] - grown < 0.1 * unsure[1, 0, 0]  # about the rows' own now
    assert sigma == pytest.approx(np.sqrt(np.linalg.eigvalsh(fused_cov).max()))
    mean, mean_cov = v.copy(), cov.copy()
    measure.cross_check(mean, mean_cov, rows, cov, extractor.MEAN_COV_SCALE,
                        extractor.GAP_COV_SCALE)
    assert np.allclose(fused[[0, 2, 3]], mean[[0, 2, 3]])
    assert np.allclose(fused_cov[[0, 2, 3]], mean_cov[[0, 2, 3]])


def test_a_vertex_under_a_highlight_or_shadow_is_found_from_both_scans():
    """Where the column scan's lines reach a vertex from far (a highlight or a shadow over
    it, edges crossed at a glancing angle) its sigma passed the limit and the marker was
    refused, though the row scan knew the vertex well. Fused (``fuse_scans``), more such
    markers are found, none more wrong: on these 240 views 212 -> 215, 2 wrong either way
    (900 views a condition: highlight 67.7 -> 70.4 %, hard shadow 93.6 -> 95.0 %, small
    94.9 -> 95.7 %; docs/measured.md)."""
    conditions = ("specular highlight, clipped", "hard cast shadow (x0.35)",
                  "small: 25-40 px across")
    views = [v.rendered for c in conditions for v in hard_views(c, 80, seed=5)
             if v.rendered.marker_visible]
    _gains(views, ExtractorParams(fuse_scans=False), 2, "the scans fused")


def test_the_joint_fit_takes_each_edge_from_both_scans_points():
    """lines.fit_joint: the column scan's upper and lower chains and the row scan's left and
    right ones, each point given to its edge by the vertices it is split at; a top vertex
    hidden (no point within 12 px of it on any chain) comes from the two lines, and a split
    started 3 px off settles where the lines meet."""
    from services.vertex_extractor import lines
    v = np.array([[20.0, 60.0], [52.0, 12.0], [84.0, 60.0], [52.0, 108.0]])
    rng = np.random.default_rng(3)

    def along(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
        t = np.linspace(0.0, 1.0, n)[:, None]
        pts = a + t * (b - a)
        far = np.linalg.norm(pts - v[1], axis=1) > 12.0  # the top vertex hidden
        return pts[far] + rng.normal(0.0, 0.05, pts[far].shape)

    upper = np.vstack([along(v[0], v[1], 30), along(v[1], v[2], 30)])  # by x
    lower = np.vstack([along(v[0], v[3], 30), along(v[3], v[2], 30)])
    left = np.vstack([along(v[1], v[0], 45), along(v[0], v[3], 45)])  # by y
    right = np.vstack([along(v[1], v[2], 45), along(v[2], v[3], 45)])
    start = v + np.array([[0.0, 3.0], [3.0, 0.0], [0.0, -3.0], [-3.0, 0.0]])
    status, found, residual, cov, sigma = lines.fit_joint(
        upper, lower, left, right, start, 2.0, 4, 52.0, 60.0, 0.2, 1.0, 0.0)
    assert status == lines.FIT_OK
    assert np.abs(found - v).max() < 0.15, found - v
    assert residual < 0.1 and sigma < 0.2 and cov.shape == (4, 2, 2)
    status, *_ = lines.fit_joint(upper[:2], lower, left[:1], right, start, 2.0, 4, 52.0,
                                 60.0, 0.2, 1.0, 0.0)
    assert status == lines.TOO_FEW_POINTS  # the upper left edge: 2 + 1 points (< 4)


def test_a_highlight_over_a_vertex_is_found_from_both_scans_points_at_once():
    """Under a highlight the two scans' vertices, even weighted, were still too uncertain
    for 42 of 900 views; fitted to both scans' points at once, an edge has more points
    further apart (``joint_fit``): on these 120 views 89 -> 92 found, 2 wrong either way
    (900 views: 70.4 -> 72.6 %, the same 5 wrong)."""
    views = [v.rendered for v in hard_views("specular highlight, clipped", 120, seed=6)
             if v.rendered.marker_visible]
    _gains(views, ExtractorParams(joint_fit=False), 2, "the joint fit")


def test_a_highlight_that_fails_both_scans_lines_is_fitted_from_both_scans_points():
    """A highlight washing out a vertex and much of an edge leaves too few points on some
    edge of the column scan and of the row scan alike, each measuring the stretches the
    other misses: fitted to both scans' points at once, split where each chain turns
    (``both_scans_under_highlight``), such a marker is found, within what it reports; off,
    it is refused for too few points. On these 120 views 3 more found, none wrong (900
    views: 72.6 -> 75.3 %, the same 3 wrong; docs/measured.md)."""
    views = [v.rendered for v in hard_views("specular highlight, clipped", 120, seed=6)
             if v.rendered.marker_visible]
    off = ExtractorParams(both_scans_under_highlight=False, highlight_model=False)
    r = views[20]
    refused = RhombusExtractor(off).extract(r.image)
    assert not refused.found and "too few edge points" in refused.reason, refused.reason
    det = RhombusExtractor(ExtractorParams(highlight_model=False)).extract(r.image)
    assert det.found, det.reason
    assert np.linalg.norm(det.vertices_px - r.vertices_px, axis=1).max() < 0.5
    _within_reported([(det, r)])
    _gains(views, off, 2, "both scans' points under a highlight")


def test_a_highlight_clips_the_ink_along_the_edges_beside_it_only():
    """``clipped_edge_share`` (the bench's split of the highlight's views): a highlight on
    the top vertex clips the ink along both edges there, not along the bottom ones; without
    a highlight nothing clips."""
    plain = _view(_style())
    assert not clipped_edge_share(plain.image, plain.vertices_px).any()
    r = _view(_style(specular_gain=6.0, specular_radius=0.4, specular_at=(0.0, -0.9)))
    share = clipped_edge_share(r.image, r.vertices_px)  # left-top, top-right, right-bottom, ...
    assert share[0] > 0.3 and share[1] > 0.3, share
    assert share[2] == 0.0 and share[3] == 0.0, share


def test_under_a_highlight_a_marker_whose_edges_are_each_half_measurable_is_found():
    """Where no edge's ink clips over half its length, the highlight leaves every edge a
    line's worth of points: on 900 views (seeds 2024, 7, 11) 96.2 % of those 449 are found,
    against 54 % of the 451 where an edge clips over half (docs/measured.md). Here 150
    views: at least 90 % of the half-measurable ones found, none wrong."""
    views = [v.rendered for v in hard_views("specular highlight, clipped", 150, seed=8)
             if v.rendered.marker_visible]
    measurable = [r for r in views if clipped_edge_share(r.image, r.vertices_px).max() < 0.5]
    errors, wrong, n, dets = _extract_all(measurable)
    print(f"\nhalf-measurable highlight views: {len(errors)} of {n} found, {wrong} wrong")
    assert n >= 50
    assert len(errors) >= 0.9 * n and wrong == 0
    _within_reported(dets)


def test_the_rows_instead_are_checked_against_the_columns_measured_edge_points():
    """measure.points_off: points on the quadrilateral's edges are 0 px off; a stretch of
    one edge tilted (1 px at one end, 0 at the other) is 1 px off at that end; points of an
    occluder's boundary (3 px inside) and those next to a vertex are left out; an edge with
    too few points says nothing."""
    from services.vertex_extractor import measure
    v = np.array([[20.0, 60.0], [52.0, 12.0], [84.0, 60.0], [52.0, 108.0]])
    t = np.linspace(0.2, 0.8, 12)[:, None]

    def stretch(a: int, b: int, inward_px: np.ndarray) -> np.ndarray:
        e = v[b] - v[a]
        normal = np.array([e[1], -e[0]]) / np.linalg.norm(e)
        inward = normal * np.sign(normal @ (v.mean(0) - v[a]))
        return v[a] + t * e + inward_px[:, None] * inward

    zero = np.zeros(12)
    upper = np.vstack([stretch(0, 1, zero), stretch(1, 2, zero)])
    lower = np.vstack([stretch(3, 0, zero)])
    assert measure.points_off(upper, lower, v, 2.0, 4) == pytest.approx(0.0, abs=1e-9)
    tilted = stretch(1, 2, np.linspace(0.0, 1.0, 12))
    assert measure.points_off(tilted, lower, v, 2.0, 4) == pytest.approx(1.0)
    arm = stretch(1, 2, np.where(np.arange(12) < 6, 0.0, 3.0))
    assert measure.points_off(arm, lower, v, 2.0, 4) == pytest.approx(0.0, abs=1e-9)
    assert measure.points_off(tilted[:3], lower, v, 2.0, 4) == pytest.approx(0.0, abs=1e-9)
    nan = np.full((3, 2), np.nan)
    assert measure.points_off(np.vstack([tilted, nan]), lower, v, 2.0, 4) == pytest.approx(1.0)


def test_a_marker_measured_along_its_rows_instead_is_refused_where_the_columns_disagree():
    """A marker whose column lines failed (too few points on an edge under a shadow, a small
    one) is measured along its rows, with no second scan to check it: 25 of 1 235 such
    detections on 21 000 views were 2-5 px off. Where its lines miss the column scan's
    measured edge points by more than 1.5 px (``check_rows_instead``) it is refused: on
    these views (3 of them such detections, 2.1-5.1 px off) fewer are wrong and hardly any
    right one is lost. Shown alone (the rows' lines as they are, ``joint_rows_instead``
    off): 1 500 views a condition, small 4 -> 1 wrong, soft shadow 13 -> 11, 18 refused in
    all 21 000; with the joint fit on, the check takes 38 -> 36 wrong in all
    (docs/measured.md)."""
    views = [v.rendered for c, n, seed in (("small: 25-40 px across", 120, 2024),
                                           ("small: 25-40 px across", 138, 11),
                                           ("soft cast shadow (x0.35, 8-40 px)", 46, 7))
             for v in hard_views(c, n, seed=seed) if v.rendered.marker_visible]
    counts = {}
    alone = {"joint_rows_instead": False}
    for name, params in (("off", ExtractorParams(check_rows_instead=False, **alone)),
                         ("on", ExtractorParams(**alone))):
        errors, wrong, _, _ = _extract_all(views, params)
        counts[name] = (len(errors), wrong)
    print(f"\nthe rows checked: found, wrong without it {counts['off']}, with it {counts['on']}")
    removed = counts["off"][1] - counts["on"][1]
    assert removed >= 2, counts
    assert counts["off"][0] - counts["on"][0] <= removed + 1, counts  # few right ones lost


def test_a_small_marker_refused_as_off_the_columns_gets_the_small_markers_second_try():
    """A 25-40 px marker whose rows stand in for its failed columns and miss their points
    (``ROWS_OFF``) is measured again with the small markers' parameters, as one whose
    columns were too few: here it is then found 0.2 px off (with the first parameters'
    rows alone it was 2.9 px off)."""
    from services.vertex_extractor import measure
    views = [v.rendered for v in hard_views("small: 25-40 px across", 120, seed=2024)
             if v.rendered.marker_visible]
    r = views[119]
    ex = RhombusExtractor()
    lut, model = ex.params.colour.lut, ex.params.colour.vector
    cx, cy = r.vertices_px.mean(0).astype(int)
    assert measure.measure(read_only(r.image), int(cx), int(cy), 8, lut, model,
                           ex._prm)[0] == measure.ROWS_OFF
    det = ex.extract(r.image)
    assert det.found, det.reason
    assert np.linalg.norm(det.vertices_px - r.vertices_px, axis=1).max() < 1.0


def test_a_marker_measured_along_its_rows_instead_is_fitted_with_the_columns_points_too():
    """Where the rows are used instead of the columns, each edge is fitted to both scans'
    measured points at once (``joint_rows_instead``): the columns' points pull back an edge
    that a shadow over part of it (or a small marker's few rows) tilted. On these 210 small
    markers more are found and fewer wrong (1 500 views a condition: small 95.9 -> 96.4 %
    found, 1 -> 0 wrong; hard shadow 94.5 -> 94.9 %, 12 -> 11; docs/measured.md)."""
    views = [v.rendered for v in hard_views("small: 25-40 px across", 210, seed=5)
             if v.rendered.marker_visible]
    _gains(views, ExtractorParams(joint_rows_instead=False), 3,
           "the rows instead fitted with the columns' points")


def test_an_uncertain_column_scan_is_not_found_on_the_narrow_second_try_alone():
    """A highlight over the right vertex: the column scan is too uncertain, the rows disagree
    with it (a refusal the narrow window's second try is for), and the narrow window's
    column scan alone, its rows failing, puts the vertex 2.8 px off at a reported 1.1 px.
    Such a second try is kept only where the row scan agrees: the marker is refused. (The
    view this test first used, seed 7's 88th, no longer makes that wrong second try since
    ``lines.robust_split`` breaks its ties at the lines' crossing. The scans' refusal is
    tested without the whole-marker highlight fit, which since stop 57 finds this view:
    its glow clips no pixel white.)"""
    from services.vertex_extractor import measure
    r = list(hard_views("specular highlight, clipped", 66, seed=99))[65].rendered
    ex = RhombusExtractor(ExtractorParams(highlight_model=False))
    det = ex.extract(r.image)
    assert not det.found and "disagree" in det.reason, det.reason
    image = read_only(r.image)
    x, y, radius = ex._coarse_search(image)[0]  # type: ignore[misc]
    narrow = ex._prm.copy()
    narrow[measure.WINDOW] = ex.params.narrow_window
    status, stats, v, _, _, _ = measure.measure(image, x, y, radius, ex.params.colour.lut,
                                                ex.params.colour.vector, narrow)
    assert status == measure.FOUND and stats[measure.CHECKED] == 0  # the columns alone
    assert np.linalg.norm(v - r.vertices_px, axis=1).max() > 2.0  # ... and wrong


def _nees(dets: list) -> tuple[np.ndarray, np.ndarray]:
    """Per vertex: squared error normalised by its reported covariance, the marker's size."""
    from services.vertex_extractor.covariance import size_px
    nees, sizes = [], []
    for det, r in dets:
        cov = det.vertices_cov_px2
        assert cov.shape == (4, 2, 2) and np.all(np.linalg.eigvalsh(cov) > 0)
        e = det.vertices_px - r.vertices_px
        nees += [float(e[k] @ np.linalg.solve(cov[k], e[k])) for k in range(4)]
        sizes += [size_px(r.vertices_px)] * 4
    return np.array(nees), np.array(sizes)


@pytest.mark.slow  # many renders
def test_vertex_uncertainty_is_honest_on_webcam_renders_at_every_size():
    """Squared vertex errors normalised by the reported covariance average 2 per vertex (a
    chi-square with 2 degrees of freedom), between 1.5 and 3, on small and large markers
    alike: the line fits' covariance alone shrinks as 1/N with the edge points, and made a
    large marker's vertices (over 110 px) 2-3 times surer than they are (NEES 4.2), a small
    one's (under 60 px) too unsure (1.3)."""
    dets = [d for s in (1, 2, 4) for d in _run("clean", 60, seed=s)[3]]
    nees, size = _nees(dets)
    assert 1.5 <= np.mean(nees) <= 3.0, np.mean(nees)
    for part in (size < 60, size >= 110):
        assert part.sum() >= 100 and 1.7 <= np.mean(nees[part]) <= 3.0, (
            part.sum(), np.mean(nees[part]))


@pytest.mark.slow  # many renders
def test_a_soft_shadows_misplaced_edges_are_in_the_reported_uncertainty():
    """A soft shadow's boundary along or near an edge moves it by a fraction of a px with the
    lines straight and both scans agreeing: the covariance covered only the scans' noise
    (NEES 3.2 on 900 views, 5.4 on markers under 60 px). The profile's offsets show such an
    edge; the vertices next to it are reported that much less certain."""
    dets = [d for s in (1, 2) for d in _run("soft cast shadow (x0.35, 8-40 px)", 60, seed=s)[3]]
    nees, _ = _nees(dets)
    assert 1.5 <= np.mean(nees) <= 3.0, np.mean(nees)


@pytest.mark.slow  # many renders
def test_blur_is_found_right_with_an_uncertainty_that_covers_it():
    """Motion blur and defocus spread steep edges along the columns: the column scan alone was
    > 2 px off on 2-3 % of these frames with a covariance 9x too small (NEES about 18); checked
    against the row scan, at most one frame in 120 is wrong and the NEES stays below 6."""
    for condition in ("motion blur 3-10 px", "defocus 2-4 px"):
        errors, wrong, total, dets = _run(condition, 60)
        nees = []
        for det, r in dets:
            e = det.vertices_px - r.vertices_px
            nees += [float(e[k] @ np.linalg.solve(det.vertices_cov_px2[k], e[k]))
                     for k in range(4)]
        assert wrong <= 1 and len(errors) >= 0.95 * total, (condition, wrong, len(errors), total)
        assert np.mean(nees) < 6.0, (condition, np.mean(nees))


def test_the_column_and_row_scans_disagreeing_is_refused_with_its_reason():
    from services.vertex_extractor import extractor, measure
    v = np.array([[10.0, 50.0], [40.0, 10.0], [70.0, 50.0], [40.0, 90.0]])
    cov = np.tile(0.01 * np.eye(2), (4, 1, 1))

    def checked(offset_px: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, float]:
        mean, mean_cov = v.copy(), cov.copy()
        gap = measure.cross_check(mean, mean_cov, v + np.array(offset_px), cov,
                                  extractor.MEAN_COV_SCALE, extractor.GAP_COV_SCALE)
        return mean, mean_cov, gap

    near, near_cov, gap = checked((0.0, 1.0))
    assert gap == 1.0 <= extractor.MAX_SCAN_DISAGREEMENT_PX
    assert np.allclose(near, v + np.array([0.0, 0.5]))
    assert np.all(near_cov[:, 1, 1] >= 0.25)  # half the disagreement, squared
    _, _, gap = checked((3.0, 0.0))
    assert gap > extractor.MAX_SCAN_DISAGREEMENT_PX
    stats = np.zeros(measure.N_STATS)
    stats[measure.GAP] = gap
    prm = extractor.RhombusExtractor()._prm
    assert "disagree by 3.0 px" in extractor._reason(measure.DISAGREE, stats, prm)


def test_the_simulator_takes_its_hazards_from_the_deployment():
    from services.core.world import World
    from services.runtime.config import ConfigError, parse_deployment
    from services.sim.service import build_world
    dep = parse_deployment({"services": {"sim": {"hazards": {
        "shadow_factor": 0.4, "shadow_softness_px": 20, "distractors": ["card", "cup"]}}}})
    config = dep.settings["sim"]
    world = build_world(config, dep.geometry, World())  # type: ignore[arg-type]
    h = world.style.hazards
    assert h is not None and h.shadow_factor == 0.4 and h.distractors == ("card", "cup")
    plain = parse_deployment({"services": {"sim": {}}})
    assert build_world(plain.settings["sim"], plain.geometry,  # type: ignore[arg-type]
                       World()).style.hazards is None
    with pytest.raises(ConfigError, match=r"hazards\.shadow_factor"):
        parse_deployment({"services": {"sim": {"hazards": {"shadow_factor": 2.0}}}})


def test_a_dim_marker_is_measured_while_its_edges_stand_out_of_the_noise():
    """Low light (exposure x0.07-0.11): the contrast limit follows the marker's own pixel
    noise, not a fixed number (a fixed 12 grey levels refused 3 frames in 10)."""
    errors, wrong, total, dets = _run("low light (exposure x0.12)", 20)
    assert wrong == 0 and len(errors) >= 0.95 * total, (wrong, len(errors), total)
    _within_reported(dets)


def test_a_small_markers_blurred_fringe_does_not_refuse_it_but_a_bigger_blob_does():
    from services.vertex_extractor import lines
    v = np.array([[10.0, 30.0], [22.0, 12.0], [34.0, 30.0], [22.0, 48.0]])  # 24 x 36 px
    area = 0.5 * 24 * 36

    def verdict(blob: float) -> int:
        return lines.check_rhombus(v, 0.1, blob, 640, 480, 20.0, 1.0)[0]
    # through the webcam a 25-40 px marker's blob exceeds its quadrilateral by 4.5-9 sqrt(area)
    assert verdict(area + 9.0 * np.sqrt(area)) == lines.PLAUSIBLE
    assert verdict(1.15 * area + 12.0 * np.sqrt(area)) == lines.AREA_MISMATCH
    assert verdict(0.6 * area) == lines.AREA_MISMATCH  # most of the blob missing


def test_a_glossy_prints_highlight_is_walked_through_and_never_wrong():
    """The walk goes on through the highlight's halo (the marker's colour plus white light)
    and leaves out the edge points on its clipped core: half the views or more are found
    (a third before), none wrong."""
    errors, wrong, total, dets = _run("specular highlight, clipped", 30)
    assert wrong == 0, f"{wrong} of {total} wrong"
    assert len(errors) >= 0.5 * total, (len(errors), total)
    _within_reported(dets)


def test_a_clipped_core_over_the_markers_middle_leaves_its_inside_level_to_other_rows():
    """Where a glossy print's clipped core covers the middle row of every column, the
    marker's inside level is read a quarter of each run from its ends ("marker contrast too
    low (0 grey levels)" before)."""
    from services.vertex_extractor.colour import ColourModel, is_marker
    cm = ColourModel()
    views = list(hard_views("specular highlight, clipped", 7, seed=5))
    for k in (0, 6):
        r = views[k].rendered
        (lx, ly), (tx, ty), (rx, ry), (bx, by) = r.vertices_px
        middles = []
        for x in range(int(np.ceil(lx)) + 2, int(rx) - 1):  # columns with an 8 px run or more
            top = ly + (x - lx) * (ty - ly) / (tx - lx) if x <= tx else \
                ty + (x - tx) * (ry - ty) / (rx - tx)
            bottom = ly + (x - lx) * (by - ly) / (bx - lx) if x <= bx else \
                by + (x - bx) * (ry - by) / (rx - bx)
            if bottom - top >= 8:
                middles.append(is_marker(r.image, int((top + bottom) / 2), x, cm.lut, cm.vector))
        assert len(middles) > 30 and not any(middles), k  # the core over every middle
        det = RhombusExtractor().extract(r.image)
        assert det.found, (k, det.reason)
        assert np.linalg.norm(det.vertices_px - r.vertices_px, axis=1).max() < 1.5, k
        _within_reported([(det, r)])


def test_the_halo_is_the_marker_plus_white_but_a_blurred_fringe_over_grey_is_not():
    from services.vertex_extractor.colour import ColourModel, chroma_amount, is_lit_marker
    cm = ColourModel()
    lut, m = cm.lut, cm.vector

    def pixel(linear_bgr: tuple[float, float, float]) -> np.ndarray:
        v = np.clip(np.array(linear_bgr), 0, 1)
        srgb = np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
        return np.round(srgb * 255).astype(np.uint8).reshape(1, 1, 3)

    ink = pixel((0.6, 0.0, 0.6))
    chroma = 0.85 * chroma_amount(ink, 0, 0, lut)
    halo = pixel((0.85, 0.25, 0.85))          # the ink plus 0.25 white
    fringe = pixel((0.3 + 0.3, 0.3, 0.3 + 0.3))  # half ink, half a 0.6 grey wall
    assert is_lit_marker(ink, 0, 0, lut, m, chroma, True)
    assert not cm.mask(halo)[0, 0] and is_lit_marker(halo, 0, 0, lut, m, chroma, True)
    assert not is_lit_marker(fringe, 0, 0, lut, m, chroma, False)
    clipped = pixel((1.0, 0.5, 1.0))           # ink channels clipped in the halo
    assert is_lit_marker(clipped, 0, 0, lut, m, chroma, False)      # walked through
    assert not is_lit_marker(clipped, 0, 0, lut, m, chroma, True)   # but not measured
    assert not is_lit_marker(pixel((1.0, 1.0, 1.0)), 0, 0, lut, m, chroma, False)


def test_the_numpy_colour_tests_are_the_kernels_pixel_for_pixel():
    """``colour.inside_mask`` and ``lit_marker_mask`` (the fits' whole-crop tests, numpy) give
    the kernels' ``is_marker`` and ``is_lit_marker`` on every pixel in float64 (random
    colours, the marker's family: ink plus white, clipped or not), for the default model and
    a learned one's tilted ellipse; in the fits' float32, but for a colour on the ellipse's
    rim to rounding (1 of the 16.7 million for the default model)."""
    from services.vertex_extractor.colour import (
        ColourModel,
        inside_mask,
        is_lit_marker,
        is_marker,
        lit_marker_mask,
    )
    rng = np.random.default_rng(3)
    ink = np.array([200.0, 0.0, 220.0])
    family = ink * rng.uniform(0.2, 1.0, (3000, 1)) + rng.uniform(0, 255, (3000, 1)) \
        + rng.normal(0, 12, (3000, 3))
    img = np.concatenate([rng.integers(0, 256, (3000, 3)), np.clip(family, 0, 255)]
                         ).astype(np.uint8).reshape(60, 100, 3)
    chroma = 0.85 * 150.0
    tilted = ColourModel(centre=(0.6, 0.03), covariance=((0.0064, 0.0008), (0.0008, 0.0004)))
    for cm in (ColourModel(), tilted):
        lut, m = cm.lut, cm.vector
        for unclipped in (False, True):
            kernel = np.array([[is_lit_marker(img, y, x, lut, m, chroma, unclipped)
                                for x in range(100)] for y in range(60)])
            assert 300 < kernel.sum() < 5700  # (both kinds of pixel)
            ours = lit_marker_mask(lut[img], m, chroma, unclipped)
            assert (ours == kernel).all(), (cm.centre, unclipped, int((ours != kernel).sum()))
            single = lit_marker_mask(lut.astype(np.float32)[img], m, chroma, unclipped)
            assert (single != kernel).sum() <= 3
        inside = np.array([[is_marker(img, y, x, lut, m) for x in range(100)]
                           for y in range(60)])
        assert 100 < inside.sum() and (inside_mask(lut[img], m) == inside).all()
        assert (cm.mask(img) == inside).all()


def test_a_vertex_whose_edges_do_not_step_there_is_refused_unless_it_is_hidden():
    from services.vertex_extractor.profile import odd_vertex, vertex_steps
    # eight stretches: edge k next to vertex k, then edge k next to vertex k + 1
    assert odd_vertex(np.array([0.1, 0.0, -0.1, 0.0, 0.1, 0.0, 0.0, 0.1]), 1.0) == (-1, 0.0)
    k, deviation = odd_vertex(np.array([0.1, 0.0, -0.1, 0.0, 0.1, 0.0, -1.6, 0.1]), 1.0)
    assert k == 3 and abs(deviation - 1.6) < 1e-9    # edge 2 (lower right) next to the bottom
    assert odd_vertex(np.array([np.nan, 0.0, -1.5, 0.0, 0.1, 0.0, 0.0, 0.1]), 1.0)[0] == 2
    # an arm over the top vertex: its two stretches are not read
    cm = RhombusExtractor().params.colour
    img = np.full((120, 160, 3), 90, np.uint8)
    v = np.array([[30.0, 60.0], [80.0, 20.0], [130.0, 60.0], [80.0, 100.0]])
    cv2.fillConvexPoly(img, np.round(v * 16).astype(np.int32), (200, 40, 200), cv2.LINE_AA, 4)
    img[15:38, 70:91] = (60, 120, 200)  # skin over the top vertex
    steps = vertex_steps(read_only(img), v, cm.lut, cm.vector)
    assert np.isnan(steps[1]) and np.isnan(steps[4])       # next to the hidden top vertex
    seen = steps[[0, 2, 3, 5, 6, 7]]  # alike (an sRGB-drawn edge's steps lie off it alike)
    assert np.all(np.abs(seen - np.median(seen)) < 0.1) and odd_vertex(steps, 1.0)[0] == -1
