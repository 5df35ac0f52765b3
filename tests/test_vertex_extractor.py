import asyncio
import math
import time

import cv2
import numpy as np
import pytest

from schemas import MarkerVertices, ServiceStats
from schemas.keys import FRAME, VERTICES
from services.runtime.config import parse_deployment
from services.runtime.launcher import run_deployment
from services.sim.scenes import random_views
from services.vertex_extractor.colour import ColourModel, grid_mask
from services.vertex_extractor.extractor import (
    Detection,
    ExtractorParams,
    RhombusExtractor,
    read_only,
)
from services.vertex_extractor.lines import best_split, robust_split
from tests.conftest import wait_alive_async, wait_matched
from tests.helpers.fake_frames import publish_frame, render_marker


@pytest.fixture(scope="module")
def accuracy_run():
    """500 seeded simulator views: 15-80 cm, up to 50 deg off the normal, roll up to 15 deg,
    noise 1-4 grey levels, 30% motion-blurred, brightness 0.5-1.0 (above, 8 bits clip the
    magenta), clutter and distractors."""
    ex = RhombusExtractor()
    errors, found, total = [], 0, 0
    for view in random_views(500, seed=11):
        ex.reset()
        det = ex.extract(view.rendered.image)
        total += 1
        if det.found:
            found += 1
            errors.append(np.linalg.norm(det.vertices_px - view.rendered.vertices_px, axis=1))
    return np.concatenate(errors), found, total


def test_vertex_accuracy_on_500_simulated_views(accuracy_run):
    errors, _, _ = accuracy_run
    assert np.median(errors) <= 0.1, f"median {np.median(errors):.3f} px"
    assert np.percentile(errors, 95) <= 0.3, f"p95 {np.percentile(errors, 95):.3f} px"


def test_found_in_at_least_97_percent_of_views(accuracy_run):
    _, found, total = accuracy_run
    assert found / total >= 0.97, f"found {found}/{total}"


def test_no_detection_without_a_marker():
    """Frames with the humanoid's body, clutter and pink distractors, but no marker."""
    ex = RhombusExtractor()
    from services.core.camera import CameraModel
    from services.core.mounts import Geometry
    from services.sim.render import RenderStyle, render_view
    from services.sim.scenes import marker_pose
    cam, g = CameraModel.paper(), Geometry()
    T = marker_pose(0.3, 320, 240, cam)
    for seed in range(6):
        r = render_view(cam, T, marker_points_m=g.marker_points(), style=RenderStyle(seed=seed),
                        draw_marker=False)
        ex.reset()
        det = ex.extract(r.image)
        assert not det.found and det.reason


def test_vertices_are_ordered_left_top_right_bottom_and_convex():
    ex = RhombusExtractor()
    for view in random_views(40, seed=21):
        ex.reset()
        det = ex.extract(view.rendered.image)
        assert det.found, det.reason
        v = det.vertices_px
        assert v[0, 0] < v[2, 0] and v[1, 1] < v[3, 1]           # left < right, top above
        assert v[0, 0] == v[:, 0].min() and v[1, 1] == v[:, 1].min()
        e = np.roll(v, -1, axis=0) - v
        cross = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
        assert np.all(cross > 0)  # clockwise on screen (y down): convex, consistent order


def test_tracking_uses_the_previous_frame_and_agrees_with_a_cold_search():
    r = render_marker(0.35, 300, 220, 25.0)
    ex = RhombusExtractor()
    cold = ex.extract(r.image)
    tracked = ex.extract(r.image)
    assert cold.found and not cold.tracked and tracked.tracked
    assert np.abs(cold.vertices_px - tracked.vertices_px).max() < 1e-6


def test_a_near_marker_is_measured_on_at_most_max_columns_columns():
    """A marker 250 px wide is measured on every 4th column and row (at most 64 of each),
    and where that is found and cross-checked it is the detection: as far from the truth as
    every column's measurement, within its reported uncertainty, which is about every
    column's."""
    from services.vertex_extractor import measure
    r = render_marker(0.15, 320, 240, 20.0)
    ex = RhombusExtractor()
    p = ex.params
    assert p.max_columns == 64
    det = ex.extract(r.image)
    assert det.found, det.reason
    fast = ex._prm.copy()
    fast[measure.MAX_COLUMNS] = p.max_columns
    seed = ex._seed
    assert seed is not None
    image = read_only(r.image)  # (as the extractor passes frames: the kernels' compiled type)
    capped = measure.measure(image, *seed, p.colour.lut, p.colour.vector, fast)
    full = measure.measure(image, *seed, p.colour.lut, p.colour.vector, ex._prm)
    assert capped[0] == full[0] == measure.FOUND
    assert capped[1][measure.CAPPED] == 1 and capped[1][measure.CHECKED] == 1
    assert capped[1][measure.COLUMNS] <= 64 < 150 < full[1][measure.COLUMNS]
    assert full[1][measure.CAPPED] == 0
    assert np.abs(ex.extract(r.image).vertices_px - capped[2]).max() < 1e-9  # (tracked)
    err_capped = np.linalg.norm(capped[2] - r.vertices_px, axis=1)
    err_full = np.linalg.norm(full[2] - r.vertices_px, axis=1)
    assert err_capped.max() < 0.3 and err_full.max() < 0.3, (err_capped, err_full)
    assert det.vertices_cov_px2 is not None
    sigma = np.sqrt(det.vertices_cov_px2[:, [0, 1], [0, 1]].sum(axis=1))
    assert np.all(np.linalg.norm(capped[2] - full[2], axis=1) < 3 * sigma)
    # points 4 columns apart share fewer pixels: their covariance scaled by COV_SCALE / 4, so
    # about every column's (unscaled it would be 4 times as large)
    trace = capped[3][:, 0, 0] + capped[3][:, 1, 1]
    trace_full = full[3][:, 0, 0] + full[3][:, 1, 1]
    assert np.all((trace > 0.5 * trace_full) & (trace < 2.0 * trace_full)), (trace, trace_full)


def test_a_near_marker_not_found_and_cross_checked_on_fewer_columns_is_measured_on_all(
        monkeypatch):
    """The scans on every k-th column are a first try only: where they are not both found
    and agreeing, the marker is measured on every column, as with ``max_columns = 0``."""
    from services.vertex_extractor import measure
    r = render_marker(0.15, 320, 240, 20.0)
    every = RhombusExtractor(ExtractorParams(max_columns=0)).extract(r.image)
    real = measure.measure
    caps: list[float] = []

    def unchecked(img, x, y, radius, lut, m, prm):  # type: ignore[no-untyped-def]
        out = real(img, x, y, radius, lut, m, prm)
        caps.append(float(prm[measure.MAX_COLUMNS]))
        if prm[measure.MAX_COLUMNS] > 0:
            out[1][measure.CHECKED] = 0.0  # (as if the row scan had failed)
        return out

    monkeypatch.setattr(measure, "measure", unchecked)
    det = RhombusExtractor().extract(r.image)
    assert det.found and every.found
    assert caps[:2] == [64.0, 0.0]  # (the marker's blob first; then any other blob's)
    assert np.abs(det.vertices_px - every.vertices_px).max() < 1e-9


def _bowed_chains(sag_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A rhombus's upper and lower chains of edge points (every column, 0.05 px noise), each
    edge bowed outward by ``sag_px`` at its middle (a barrel lens, a curled print), and its
    true vertices (left, top, right, bottom)."""
    rng = np.random.default_rng(0)
    v = np.array([[100.0, 200.0], [160.0, 140.0], [220.0, 200.0], [160.0, 260.0]])

    def edge(p: np.ndarray, q: np.ndarray, out: float) -> np.ndarray:
        xs = np.arange(p[0] + 1, q[0] + 1)
        f = (xs - p[0]) / (q[0] - p[0])
        ys = p[1] + f * (q[1] - p[1]) + out * sag_px * 4 * f * (1 - f)
        return np.stack([xs, ys + rng.normal(0, 0.05, xs.size)], axis=1)
    u = np.concatenate([edge(v[0], v[1], -1.0), edge(v[1], v[2], -1.0)[:-1]])
    d = np.concatenate([edge(v[0], v[3], 1.0), edge(v[3], v[2], 1.0)[:-1]])
    return np.ascontiguousarray(u), np.ascontiguousarray(d), v


def test_a_bowed_edges_bias_at_the_vertex_is_in_its_covariance():
    """Four lines fitted to bowed edges meet off the true vertices (0.6-0.8 px for a 1 px
    bow), by a bias the points' number does not average out: the reported covariance carries
    it (each vertex within 3 sigma), where on straight edges it stays the points' noise's.
    The largest sigma that refuses a marker as too uncertain is the noise's alone."""
    from services.vertex_extractor.lines import FIT_OK, fit_rhombus_robust
    for sag_px, worst in ((0.0, 0.1), (1.0, 1.0)):
        u, d, truth = _bowed_chains(sag_px)
        status, v, _, cov, sigma_max = fit_rhombus_robust(u, d, 4, 2, 160.0, 200.0, 0.3, 5.0,
                                                          0.0004)
        assert status == FIT_OK
        e = v - truth
        assert np.linalg.norm(e, axis=1).max() < worst
        chi2 = [float(e[i] @ np.linalg.solve(cov[i], e[i])) for i in range(4)]
        assert max(chi2) < 9.0, (sag_px, chi2)
        sigma = np.sqrt(cov[:, 0, 0] + cov[:, 1, 1])
        if sag_px == 0.0:
            assert sigma.max() < 0.1  # (nothing added where the edges are straight)
        else:
            assert np.linalg.norm(e, axis=1).min() > 0.4  # (the bow does move the vertices)
            assert sigma.min() > 0.4 and sigma_max < 0.3  # (reported; not refused for it)


def test_a_bows_variance_is_its_square_less_its_noise_variance():
    """The bias added at a vertex is the fitted departure squared less its noise variance
    once (the unbiased estimate of the bias's square; ``lines.BOW_SIGMAS`` = 1): a departure
    of 0.5 px with a noise variance of 0.05 px² (sigma 0.1 px, ``COV_SCALE`` 5) adds 0.2 px²;
    one within its noise adds nothing."""
    from services.vertex_extractor.lines import _bow_variance
    row = np.zeros(20)
    row[3], row[11], row[14] = 0.1, 0.5, 1.0  # (sigma; departure and g' inv g at s = 0)
    assert _bow_variance(row, 0.0, 5.0) == pytest.approx(0.25 - 0.05)
    row[11] = 0.2
    assert _bow_variance(row, 0.0, 5.0) == 0.0


def test_optimal_split_finds_the_kink():
    x = np.arange(40, dtype=float)
    y = np.where(x < 17, 100 - 1.3 * x, 100 - 1.3 * 17 + 1.3 * (x - 17))
    k = best_split(np.column_stack([x, y]), 3)
    assert k in (17, 18)


def test_the_split_between_two_lines_does_not_hang_on_rounding():
    """Points off both lines (a rounded vertex, an occluder's boundary) cost the band's square
    on either, so the split's cost is flat across them: the split is then the one nearest
    the lines' crossing, the same under a 1e-12 px change of the points. (Rounding picked it
    before: 13, 14, 17, 21 or 29 here; on webcam renders 17 % of the column fits moved a
    vertex by more than 1e-6 px under such a change, some by tenths of a pixel.)"""
    x = np.arange(40, dtype=float)
    y = 100.0 - 0.8 * np.abs(x - 20.3)  # the upper chain of a marker, its vertex at x = 20.3
    y += np.random.default_rng(3).normal(0.0, 0.05, 40)  # (sums that round)
    y[13:29] -= 2.0  # the vertex's neighbourhood off both lines (beyond the 0.5 px band)
    points = np.column_stack([x, y])
    n = math.hypot(0.8, 1.0)
    a = np.array([-0.8 / n, 1.0 / n, (100.0 - 0.8 * 20.3) / n])  # y = 100 - 0.8 (20.3 - x)
    b = np.array([0.8 / n, 1.0 / n, (100.0 + 0.8 * 20.3) / n])  # y = 100 - 0.8 (x - 20.3)
    rng = np.random.default_rng(5)
    splits = {robust_split(points + rng.normal(0.0, 1e-12, points.shape), 20, a, b, 0.5)
              for _ in range(30)}
    assert splits == {21}  # between x = 20 and 21, where the lines cross


@pytest.mark.parametrize("model", [
    ColourModel(), ColourModel(transfer="linear"),
    ColourModel(centre=(0.45, 0.1), covariance=((0.004, 0.001), (0.001, 0.002)),
                max_distance=5.0)], ids=["default", "linear", "learned"])
def test_the_cold_searchs_green_pretest_drops_no_marker_colour(model):
    """The byte table that passes over too-green pixels is a necessary condition of the
    interior test: the grid finds the same pixels with it as without, over all 2^24 colours."""
    v = np.arange(256, dtype=np.uint8)
    every = read_only(np.stack(np.meshgrid(v, v, v, indexing="ij"), -1).reshape(4096, 4096, 3))
    with_pretest = grid_mask(every, 1, 0, model.lut, model.vector, model.green_bound)
    without = grid_mask(every, 1, 0, model.lut, model.vector, np.full(256, 255, np.uint8))
    assert with_pretest[1] == without[1] > 0
    assert np.array_equal(with_pretest[0], without[0])
    assert model.green_bound.mean() < 200  # and it passes over something


def test_every_refusal_of_the_compiled_measurement_has_its_reason():
    from services.vertex_extractor import lines, measure
    from services.vertex_extractor.extractor import _reason
    statuses = [measure.NO_SEED, measure.BORDER, measure.SMALL_AREA, measure.FEW_COLUMNS,
                measure.LOW_CONTRAST, measure.FEW_POINTS, measure.SHAPE, measure.UNCERTAIN,
                measure.DISAGREE, measure.ROWS_OFF, measure.PERSPECTIVE]
    statuses += [measure.FIT + s for s in (lines.TOO_FEW_POINTS, lines.PARALLEL,
                                           lines.HIDDEN_EDGE, lines.OUTSIDE_POINTS)]
    statuses += [measure.VERDICT + s for s in range(lines.NOT_FINITE, lines.AREA_MISMATCH + 1)]
    prm = RhombusExtractor()._prm
    reasons = {_reason(s, np.zeros(measure.N_STATS), prm) for s in statuses}
    assert len(reasons) == len(statuses) and all(reasons)


def _bad_frames():
    r = render_marker(0.3)
    img = r.image
    yield "all black", np.zeros_like(img), "no marker"
    yield "all marker colour", np.full_like(img, (255, 0, 255)), "marker-coloured"
    cut = render_marker(0.2, u=40, v=240)
    yield "cut by the border", cut.image, "border"
    two = img.copy()
    other = render_marker(0.3, u=140, v=240).image
    two[:, :240] = other[:, :240]
    yield "two markers", two, "two or more"
    hidden = img.copy()
    v = r.vertices_px
    cx, cy = v.mean(0).astype(int)
    hidden[cy - 60:cy + 5, cx - 8:cx + 70] = (40, 40, 40)
    yield "partly hidden", hidden, ("do not make a convex quadrilateral", "partly hidden",
                                    "not the whole marker")
    small = np.full_like(img, 120)  # an 18 px marker: below the smallest (25 px) found
    tiny = np.array([[313.2, 240], [320, 231], [326.8, 240], [320, 249]])
    cv2.fillConvexPoly(small, np.round(tiny * 16).astype(np.int32), (255, 0, 255),
                       cv2.LINE_AA, 4)
    yield "too small", small, "small"


@pytest.mark.parametrize("side", ["top", "bottom", "left", "right"])
@pytest.mark.parametrize("margin_px", [2.5, 5.0, 8.0])
def test_a_marker_a_few_px_from_the_border_is_found(side, margin_px):
    """A vertex a few px from the image's edge leaves its neighbours' windows no room
    outside; those edge points are left out (the whole marker used to be refused as
    "touching the border"), the vertex comes from the rest of its two edges."""
    axis, k, target = {"top": (1, 1, margin_px), "bottom": (1, 3, 479.0 - margin_px),
                       "left": (0, 0, margin_px), "right": (0, 2, 639.0 - margin_px)}[side]
    centre = np.array([320.0, 240.0])
    for _ in range(4):  # (the marker turns to face the camera: not a plain shift)
        r = render_marker(0.3, u=centre[0], v=centre[1])
        centre[axis] += target - r.vertices_px[k, axis]
    assert abs(r.vertices_px[k, axis] - target) < 0.5
    det = RhombusExtractor().extract(r.image)
    assert det.found, det.reason
    assert np.abs(det.vertices_px - r.vertices_px).max() < 0.3


@pytest.mark.parametrize("name,image,reason", list(_bad_frames()),
                         ids=[b[0] for b in _bad_frames()])
def test_bad_frames_give_found_false_with_a_reason(name, image, reason):
    det = RhombusExtractor().extract(image)
    assert not det.found and det.reason
    assert any(r in det.reason for r in ((reason,) if isinstance(reason, str) else reason))


def test_a_slow_extraction_holds_up_no_other_service(router, make_bus, monkeypatch):
    """The services of one process share its event loop, the IR transmitter's heartbeat to
    the firmware's 0.4 s watchdog among them; a marker fitted whole under a shadow takes up
    to 0.3 s. The extraction runs on its own thread: while one takes 0.6 s, the loop still
    runs every few ms, and the result is published."""
    def slow(self, image):  # type: ignore[no-untyped-def]
        time.sleep(0.6)
        return Detection(False, reason="slow on purpose")
    monkeypatch.setattr(RhombusExtractor, "extract", slow)
    dep = parse_deployment({"zenoh": {"connect": [router], "multicast_scouting": False},
                            "services": {"vertex_extractor": {}}})
    bus = make_bus("camera")

    async def go():
        out = bus.subscribe(VERTICES, MarkerVertices, latest=False, queue=8)
        service = asyncio.create_task(run_deployment(dep, duration=60))
        await wait_alive_async(bus.session, "vertex_extractor")
        await wait_matched(bus, FRAME)
        gaps = []

        async def tick() -> None:
            last = time.monotonic()
            while True:
                await asyncio.sleep(0.01)
                now = time.monotonic()
                gaps.append(now - last)
                last = now
        ticker = asyncio.create_task(tick())
        publish_frame(bus, np.zeros((480, 640, 3), np.uint8), 7)
        m = await out.recv(timeout=30)
        ticker.cancel()
        service.cancel()
        assert m.seq == 7 and not m.found and m.reason == "slow on purpose"
        assert len(gaps) > 20 and max(gaps) < 0.2, max(gaps)
    asyncio.run(go())


def test_service_publishes_vertices_and_survives_bad_frames(router, make_bus):
    dep = parse_deployment({"zenoh": {"connect": [router], "multicast_scouting": False},
                            "services": {"vertex_extractor": {}}})
    bus = make_bus("camera")
    r = render_marker(0.3)

    async def go():
        out = bus.subscribe(VERTICES, MarkerVertices, latest=False, queue=32)
        service = asyncio.create_task(run_deployment(dep, duration=60))
        await wait_alive_async(bus.session, "vertex_extractor")
        await wait_matched(bus, FRAME)
        key = bus.keys.key(FRAME)
        bus.session.put(key, b"", attachment=b'{"seq":1,"stamp_ns":1,"width":640,'
                                             b'"height":480,"encoding":"bgr8"}')
        bus.session.put(key, b"x" * 100, attachment=b'{"seq":2,"stamp_ns":1,"width":640,'
                                                    b'"height":480,"encoding":"bgr8"}')

        async def rejected() -> int:
            stats = await bus.get("stats/vertex_extractor", ServiceStats)
            return sum(stats[0].rejected.get(key, {}).values()) if stats else 0
        deadline = time.monotonic() + 30
        while await rejected() == 0:  # counted by the service's bus (the newer one, at least)
            assert time.monotonic() < deadline, "the bad frames were never counted"
            await asyncio.sleep(0.05)
        msgs = {}
        # one frame at a time (the service takes the newest frame: one sent before the last
        # was taken would be skipped)
        for seq, image in ((3, np.zeros((480, 640, 3), np.uint8)),
                           (4, cv2.cvtColor(r.image, cv2.COLOR_BGR2GRAY)), (5, r.image)):
            publish_frame(bus, image, seq)
            while seq not in msgs:
                m = await out.recv(timeout=30)
                msgs[m.seq] = m
        service.cancel()
        assert not msgs[3].found and "no marker" in msgs[3].reason
        assert not msgs[4].found and "mono8" in msgs[4].reason
        assert msgs[5].found
        err = np.abs(np.array(msgs[5].vertices_px) - r.vertices_px).max()
        assert err < 0.3
        assert msgs[5].area_ratio == pytest.approx(
            cv2.contourArea(r.vertices_px.astype(np.float32)) / (640 * 480), rel=0.01)
        assert 1 not in msgs and 2 not in msgs  # rejected by the bus, counted, not fatal
        assert math.isfinite(msgs[5].residual_px)
        cov = np.array(msgs[5].vertices_cov_px2)  # per-vertex 2 x 2, px²
        assert cov.shape == (4, 2, 2) and np.all(np.linalg.eigvalsh(cov) > 0)
        assert np.all(np.sqrt(np.linalg.eigvalsh(cov)) < 0.5)
        assert msgs[3].vertices_cov_px2 is None
    asyncio.run(go())


def _strip_shadow_views(gap_px: float, motion_blur_px: float = 0.0):
    """A webcam view of the marker 40 cm away, 30 deg off its normal, with a hard shadow (x0.35)
    whose boundary runs along the upper-right edge ``gap_px`` inside it (``gap_px`` < 0: no
    shadow); returns (image, true vertices)."""
    from dataclasses import replace

    from services.core.camera import CameraModel
    from services.core.mounts import Geometry
    from services.sim.hazards import Hazards
    from services.sim.render import INKS_BGR, RenderStyle, render_view
    from services.sim.scenes import marker_pose, random_webcam
    cam, pts = CameraModel.paper(), Geometry().marker_points()
    T = marker_pose(0.4, 330.0, 230.0, cam, math.radians(30.0), 0.1, 0.05)
    v = cam.project((T[:3, :3] @ pts.T).T + T[:3, 3])
    centre = v.mean(0)
    edge = v[2] - v[1]
    n = np.array([edge[1], -edge[0]]) / np.linalg.norm(edge)
    if n @ (v[1] - centre) < 0:
        n = -n
    half = float(np.linalg.norm(v[3] - v[1]) / 2)
    hazards = None if gap_px < 0 else Hazards(
        shadow_factor=0.35, shadow_angle_deg=math.degrees(math.atan2(n[1], n[0])),
        shadow_offset=(float(n @ (v[1] - centre)) - gap_px) / half)
    style = RenderStyle(seed=5, marker_bgr=INKS_BGR["nominal"], photos=True,
                        camera=random_webcam(np.random.default_rng(3), jpeg_quality=0),
                        motion_blur_px=motion_blur_px, motion_blur_angle_deg=60.0)
    style = replace(style, hazards=hazards)
    r = render_view(cam, T, marker_points_m=pts, style=style)
    return r.image, r.vertices_px


def test_a_shadow_boundary_along_an_edge_is_refused_not_measured_as_the_edge():
    """Issue 21: a hard shadow's boundary 3.5 px inside the upper-right edge leaves a strip
    of darker ink that the coverage sum reads as part coverage: the edge moves inward by a
    steady 2 px or more (two vertices over 2 px off without this test). Its profile is two
    steps; the scans' detection is refused, naming the edge. Fitted whole under the shadow
    (``shadow.py``, the last resort) it is found within three reported sigmas. The same view
    without the shadow, or blurred 8 px, is found to a fraction of a pixel."""
    ex = RhombusExtractor()
    for blur in (0.0, 8.0):
        img, truth = _strip_shadow_views(-1.0, blur)
        det = ex.extract(img)
        assert det.found, det.reason
        assert np.abs(det.vertices_px - truth).max() < 0.8
        ex.reset()
    img, truth = _strip_shadow_views(3.5)
    det = RhombusExtractor(ExtractorParams(shadow_model=False)).extract(img)
    assert not det.found and "upper right edge is not a clean step" in det.reason, (
        det.reason, None if det.vertices_px is None else det.vertices_px - truth)
    det = ex.extract(img)
    assert det.found and det.vertices_px is not None and det.vertices_cov_px2 is not None
    error = np.linalg.norm(det.vertices_px - truth, axis=1)
    sigma = np.sqrt(np.linalg.eigvalsh(det.vertices_cov_px2).max(axis=1))
    assert error.max() < 0.5 and np.all(error < 3 * sigma), (error, sigma)


def test_an_edge_is_odd_only_off_its_step_and_off_the_others():
    """profile.odd_edge: inward beyond 0.5 px and 0.3 px from the median; a wide blur's edges
    all off alike pass; outward up to 1.6 x the limit (a coloured surround's skew) passes."""
    from services.vertex_extractor.profile import odd_edge
    assert odd_edge(np.array([0.05, -0.6, 0.0, -0.1]), 0.5, 0.3) == 1
    assert odd_edge(np.array([-0.6, -0.55, -0.65, -0.6]), 0.5, 0.3) == -1
    assert odd_edge(np.array([0.1, 0.0, 0.7, 0.0]), 0.5, 0.3) == -1
    assert odd_edge(np.array([0.1, 0.0, 0.9, np.nan]), 0.5, 0.3) == 2
    assert odd_edge(np.full(4, np.nan), 0.5, 0.3) == -1


def test_an_edge_point_with_a_shaded_rim_inside_its_window_is_left_out():
    """scan._crossing_gap (on a column's window scores): a blurred single step's half-way
    crossing is the coverage sum's edge; a strip of shaded ink beside the edge (a shadow's
    boundary 3 px inside, ink at 35 %) moves the sum's edge by about 1 px but not the
    crossing, and the gap says so."""
    from services.vertex_extractor.scan import MAX_CROSSING_GAP_PX, _crossing_gap

    def sum_edge(values: list[float]) -> float:  # outside above (rows 0..), as scan._edge
        return len(values) - 0.5 - sum(v / 200.0 for v in values)

    step = [0, 0, 0, 0, 0, 10, 60, 140, 190, 200, 200, 200, 200]  # blurred, edge at 6.5
    shaded = [0, 0, 0, 0, 0, 10, 60, 70, 70, 70, 190, 200, 200]  # 35 % ink over 3 rows
    for values, expect_gap in ((step, False), (shaded, True)):
        edge = sum_edge(values)
        gap = _crossing_gap(np.array(values, float), 0, len(values) - 1, 0.0, 1 / 200.0, edge)
        assert (gap > MAX_CROSSING_GAP_PX) == expect_gap, (values, edge, gap)
    assert abs(sum_edge(step) - 6.5) < 0.1
