"""The camera learned from the marker's own detections (``learned_camera.py``): on views of
the rhombus projected through known cameras, with the vertices' noise their covariance
states, the focal length and principal point come back within their reported standard
errors; views far off are left out; views face on do not fix a camera and are refused; the
learner offers a camera only where a solve's older and newer halves agree, from distinct,
confident views, and none from a blend of two cameras.
On webcam renders: tests/test_highlight_fit.py."""

from collections.abc import Generator

import cv2
import numpy as np
import pytest

from services.core.mounts import Geometry
from services.vertex_extractor import learned_camera
from services.vertex_extractor.learned_camera import CameraLearner, judge, solve

W, H = 640, 480
RHOMBUS_M = Geometry().marker_points()  # (4, 3) m, left, top, right, bottom
NOISE_PX = 0.15


def _views(n: int, f: float, cx: float, cy: float, seed: int, max_tilt_deg: float = 60.0,
           noise_px: float = NOISE_PX) -> tuple[np.ndarray, np.ndarray]:
    """n views (n, 4, 2) px of the rhombus 20-80 cm away, turned up to ``max_tilt_deg`` about
    a random axis in its plane and anywhere in view, through the camera (f, cx, cy) px, with
    Gaussian noise of ``noise_px`` per axis; and the covariance that states it."""
    rng = np.random.default_rng(seed)
    K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    views: list[np.ndarray] = []
    while len(views) < n:
        axis = rng.normal(size=2)
        axis = np.r_[axis / np.linalg.norm(axis), 0.0]
        tilt = np.radians(rng.uniform(0.0, max_tilt_deg))
        roll = np.array([0.0, 0.0, np.radians(rng.uniform(-20, 20))])
        R = cv2.Rodrigues(axis * tilt)[0] @ cv2.Rodrigues(roll)[0]
        z = rng.uniform(0.2, 0.8)
        u, v = rng.uniform(60, W - 60), rng.uniform(60, H - 60)
        t = np.array([(u - cx) * z / f, (v - cy) * z / f, z])
        px = cv2.projectPoints(RHOMBUS_M, cv2.Rodrigues(R)[0], t, K, None)[0].reshape(4, 2)
        if px.min() < 5 or px[:, 0].max() > W - 5 or px[:, 1].max() > H - 5:
            continue
        views.append(px + rng.normal(0.0, noise_px, (4, 2)))
    covs = np.broadcast_to(noise_px ** 2 * np.eye(2), (n, 4, 2, 2)).copy()
    return np.array(views), covs


@pytest.mark.parametrize(("f", "cx", "cy"), [(757.0, 390.0, 260.0), (420.0, 300.0, 250.0),
                                             (1100.0, 330.0, 230.0)])
def test_a_known_camera_comes_back_within_its_standard_errors(f: float, cx: float,
                                                              cy: float) -> None:
    views, covs = _views(60, f, cx, cy, seed=int(f))
    s = solve(RHOMBUS_M, views, covs, W, H)
    assert not isinstance(s, str), s
    assert judge(s, W, H) == ""
    for got, true, se in zip((s.f, s.cx, s.cy), (f, cx, cy), s.se, strict=True):
        assert abs(got - true) < 4 * se, (got, true, se)
    assert abs(s.f - f) < 0.02 * f and np.hypot(s.cx - cx, s.cy - cy) < 10.0
    assert s.views == 60 and 0.6 < s.chi2 < 1.6  # (the noise as the covariance states it)


def test_views_far_off_are_left_out() -> None:
    views, covs = _views(60, 757.0, 390.0, 260.0, seed=3)
    views[:4, 1] += 12.0  # a vertex 12 px off on four views (a wrong detection)
    s = solve(RHOMBUS_M, views, covs, W, H)
    assert not isinstance(s, str), s
    assert 52 <= s.views <= 56  # (the four, and a view they pulled off before they were out)
    assert abs(s.f - 757.0) < 0.02 * 757.0 and np.hypot(s.cx - 390.0, s.cy - 260.0) < 10.0


def test_views_face_on_do_not_fix_the_camera() -> None:
    """The rhombus always parallel to the image: its views fix no focal length."""
    views, covs = _views(60, 757.0, 390.0, 260.0, seed=4, max_tilt_deg=0.0)
    s = solve(RHOMBUS_M, views, covs, W, H)
    assert isinstance(s, str) or judge(s, W, H) != "", s


def test_the_learner_offers_a_camera_once_its_halves_agree_from_distinct_confident_views(
) -> None:
    views, covs = _views(2 * learned_camera.MIN_VIEWS, 757.0, 390.0, 260.0, seed=5)
    learner = CameraLearner(RHOMBUS_M, W, H)
    for _ in range(3 * learned_camera.MIN_VIEWS):  # one view over and over: one view
        learner.add(views[0], covs[0])
    unsure = covs[0] * (learned_camera.MAX_SIGMA_PX / NOISE_PX) ** 2 * 1.5
    for v in views[1:]:  # too uncertain to learn from
        learner.add(v, unsure)
    for _ in range(learned_camera.MIN_VIEWS):  # not numbers: not learned from, no harm done
        learner.add(np.full((4, 2), np.nan), covs[0])
        learner.add(views[1], np.full((4, 2, 2), np.inf))
        learner.add(views[1], -covs[1])  # (no covariance: not positive definite)
    assert learner.camera() is None and learner.cameras() == []
    last = learned_camera.MIN_VIEWS - 1
    for v, c in zip(views[1:last], covs[1:], strict=False):
        learner.add(v, c)
    assert learner.camera() is None  # (one view short of the first solve)
    learner.add(views[last], covs[last])
    for _ in range(100):  # (a solve takes about 20 new views' steps)
        learner.add(views[last], covs[last])  # (not a new view: kept once, pays no step)
    assert learner.camera() is None
    frames = 0  # (the solve due is worked on a few steps a new view)
    for v, c in zip(views[last + 1:], covs[last + 1:], strict=True):
        if learner.camera() is not None:
            break
        learner.add(v, c)
        frames += 1
    assert 5 <= frames < len(views) - last - 1, (frames, learner.last)
    s = learner.camera()
    assert s is not None and abs(s.f - 757.0) < 0.02 * 757.0
    low, high = learner.cameras()
    assert low.K[0, 0] == pytest.approx(s.f * (1 - learned_camera.BAND))
    assert high.K[0, 0] == pytest.approx(s.f * (1 + learned_camera.BAND))
    assert low.K[0, 2] == s.cx and high.K[1, 2] == s.cy
    assert (low.width, low.height) == (W, H) and not low.dist.any()


def test_the_learner_never_offers_a_camera_whose_solves_disagree() -> None:
    """Views from one camera, then another (a zoom changed): the first is learned; once a
    solve has seen the second camera's views, no camera but the second is offered (none
    while the views kept are a blend of the two), and then the second is learned."""
    a, ca = _views(learned_camera.MIN_VIEWS + 60, 757.0, 390.0, 260.0, seed=6)
    b, cb = _views(3 * learned_camera.MAX_VIEWS, 500.0, 320.0, 240.0, seed=7)
    learner = CameraLearner(RHOMBUS_M, W, H)
    for v, c in zip(a, ca, strict=True):
        learner.add(v, c)
    first = learner.camera()
    assert first is not None and abs(first.f - 757.0) < 0.02 * 757.0
    offered = []
    for v, c in zip(b, cb, strict=True):
        learner.add(v, c)
        offered.append(learner.camera())
    stale = learned_camera.MAX_SOLVE_EVERY + 30  # (the first solve after the change, done)
    assert all(s is None or abs(s.f - 500.0) < 0.02 * 500.0 for s in offered[stale:]), \
        [None if s is None else round(s.f) for s in offered]
    assert any(s is None for s in offered)  # (the blends)
    assert offered[-1] is not None, learner.last


def test_a_half_seen_face_on_agrees_with_nothing() -> None:
    """The older half's views all but face on (a camera of 600 px), the newer half's tilted
    (757 px): the face-on half fixes no camera, so none is offered, though its standard
    errors are too wide to disagree."""
    a, ca = _views(learned_camera.MIN_VIEWS // 2, 600.0, 330.0, 250.0, seed=8, max_tilt_deg=6.0)
    b, cb = _views(learned_camera.MIN_VIEWS // 2, 757.0, 390.0, 260.0, seed=9)
    learner = CameraLearner(RHOMBUS_M, W, H)
    for v, c in zip(np.concatenate([a, b]), np.concatenate([ca, cb]), strict=True):
        learner.add(v, c)
    more, cm = _views(60, 757.0, 390.0, 260.0, seed=10)
    for v, c in zip(more, cm, strict=True):  # (new views: the solve due worked on to its end)
        if not (isinstance(learner.last, str) and learner.last.startswith("fewer than")):
            break
        learner.add(v, c)
    assert learner.camera() is None
    assert isinstance(learner.last, str) and learner.last.startswith("a half of the views"), \
        learner.last


def test_a_view_found_again_is_no_new_view_and_costs_no_look_through_the_views_kept(
) -> None:
    """A marker seen again where it was (tracked standing still, or found again after
    others) is not kept again, and only its first sight looks through the views kept; a view
    that moved ``NEW_VIEW_PX`` from every one kept is kept, however near the last one
    seen it came by small steps."""
    looks: list[int] = []

    class Counting(CameraLearner):
        def _nearest_kept(self, vertices_px: np.ndarray) -> tuple[int, float]:
            looks.append(1)
            return super()._nearest_kept(vertices_px)

    views, covs = _views(16, 757.0, 390.0, 260.0, seed=14)
    tall = np.linalg.norm(views[:, 3] - views[:, 1], axis=1) >= learned_camera.MIN_MARKER_PX
    views, covs = views[tall][:12], covs[tall][:12]  # (no small marker: each one is kept)
    learner = Counting(RHOMBUS_M, W, H)
    for v, c in zip(views, covs, strict=True):
        learner.add(v, c)
    assert learner._kept == 12 and len(looks) == 11
    looks.clear()
    for v, c in zip(views, covs, strict=True):  # each seen again, 5 frames in a row
        for k in range(5):
            learner.add(v + 0.3 * k, c)
    assert learner._kept == 12 and len(looks) == 12
    step = learned_camera.NEW_VIEW_PX / 4  # (a slow drift: each step near the last)
    for k in range(1, 8):  # (1.25 to 8.75 px from views[0])
        learner.add(views[0] + [k * step, 0.0], covs[0])
    assert learner._kept == 13  # (kept once 5 px from views[0], and only then)
    assert np.allclose(learner._vertices[12], views[0] + [4 * step, 0.0])


def test_small_markers_are_not_learned_from() -> None:
    """Views whose marker is under ``MIN_MARKER_PX`` tall (a 420 px camera, 0.7-0.8 m
    away: 35-40 px) are not kept: too little perspective to tell a focal length."""
    views, covs = _views(120, 420.0, 320.0, 240.0, seed=12, max_tilt_deg=50.0)
    tall = np.linalg.norm(views[:, 3] - views[:, 1], axis=1)
    learner = CameraLearner(RHOMBUS_M, W, H)
    for v, c in zip(views, covs, strict=True):
        learner.add(v, c)
    small = int((tall < learned_camera.MIN_MARKER_PX).sum())
    assert 10 <= small < 110 and learner._kept == 120 - small


def test_failed_solves_in_a_row_back_off() -> None:
    """Views that fit no camera (noise of 1.5 px stated as 0.15 px): each solve fails; the
    first ``QUICK_RETRIES`` are retried after ``SOLVE_EVERY`` new views, then each waits
    twice as long as the one before, up to ``MAX_SOLVE_EVERY``."""
    views, _ = _views(600, 757.0, 390.0, 260.0, seed=13, noise_px=1.5)
    covs = np.broadcast_to(NOISE_PX ** 2 * np.eye(2), (600, 4, 2, 2))
    waits: list[int] = []

    class Probe(CameraLearner):
        def _solving(self, views: np.ndarray, covs: np.ndarray) -> Generator[None, None, None]:
            yield from super()._solving(views, covs)
            assert self.camera() is None and isinstance(self.last, str), self.last
            waits.append(self._every)  # (new views before the next solve)

    learner = Probe(RHOMBUS_M, W, H)
    for v, c in zip(views, covs, strict=True):
        learner.add(v, c)
    every, quick = learned_camera.SOLVE_EVERY, learned_camera.QUICK_RETRIES
    assert waits[:quick + 3] == [every] * quick + [2 * every, 4 * every,
                                                   learned_camera.MAX_SOLVE_EVERY], waits


def test_the_service_logs_the_learned_camera_when_learned_and_when_it_moves(
        caplog: pytest.LogCaptureFixture) -> None:
    import logging
    from types import SimpleNamespace

    from services.vertex_extractor.service import _tell_learned
    log = logging.getLogger("test.vertex_extractor")
    first = learned_camera.Solved(760.0, 400.0, 262.0, (3.0, 2.0, 1.0), 80, 1.2)
    near = learned_camera.Solved(765.0, 401.0, 262.0, (3.0, 2.0, 1.0), 100, 1.2)
    moved = learned_camera.Solved(700.0, 380.0, 250.0, (3.0, 2.0, 1.0), 160, 1.2)
    told = None
    with caplog.at_level(logging.INFO, logger="test.vertex_extractor"):
        for solved in (None, first, near, moved):
            told = _tell_learned(SimpleNamespace(learned_camera=solved), told,  # type: ignore[arg-type]
                                 log)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2 and told is moved
    assert "focal length 760 px, principal point (400, 262) px, from 80 views" in lines[0]
    assert "focal length 700 px" in lines[1]
