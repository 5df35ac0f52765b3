import asyncio
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas import CameraPose, HumanoidPose, MarkerVertices
from schemas.keys import HUMANOID_POSE, HUMANOID_POSE_FILTERED, ODOM, VERTICES
from services.core.camera import CameraModel, undistort_px
from services.core.geometry import T_floor, inv_T
from services.core.mounts import Geometry
from services.pose_estimator import service as svc
from services.pose_estimator.estimate import (
    estimate_marker_pose,
    humanoid_floor_pose,
    up_in_camera,
)
from services.pose_estimator.evaluate import compare, pose_cases, wrong_branches
from services.pose_estimator.p4p import PoseError, ippe
from services.runtime.config import parse_deployment
from services.runtime.launcher import run_deployment
from services.sim.scenes import marker_pose
from tests.conftest import wait_alive_async

CAM = CameraModel.paper()
PTS = Geometry().marker_points()


def test_exact_recovery_on_noise_free_views():
    rng = np.random.default_rng(0)
    for _ in range(300):
        T = marker_pose(rng.uniform(0.15, 0.8), rng.uniform(150, 500), rng.uniform(120, 360),
                        CAM, math.radians(rng.uniform(-50, 50)), rng.uniform(-1, 1),
                        math.radians(rng.uniform(-15, 15)))
        v = CAM.project(PTS @ T[:3, :3].T + T[:3, 3])
        cands = ippe(PTS, undistort_px(CAM, v))
        assert np.abs(cands[0].R - T[:3, :3]).max() < 1e-6
        assert np.abs(cands[0].t - T[:3, 3]).max() < 1e-6
        est = estimate_marker_pose(CAM, v, PTS)  # no prior: the image decides
        assert np.abs(est.T_camera_marker - T).max() < 1e-6


def test_exact_recovery_with_distortion_and_skew():
    cam = CameraModel(np.array([[800.0, 1.5, 330.0], [0, 790.0, 245.0], [0, 0, 1]]),
                      np.array([-0.2, 0.1, 0.001, -0.001, 0.0]))
    T = marker_pose(0.3, 200, 150, cam, math.radians(30), 0.2, math.radians(8))
    v = cam.project(PTS @ T[:3, :3].T + T[:3, 3])
    est = estimate_marker_pose(cam, v, PTS)
    assert np.abs(est.T_camera_marker - T).max() < 1e-6


def test_both_branches_on_an_ambiguous_view_and_the_prior_chooses_right():
    # camera 25 cm above the marker looking down 30 deg: the mirror branch tilts the normal
    from services.core.geometry import T_base_camera
    T_bc = T_base_camera(0.0, 0.45, math.radians(30))
    up = up_in_camera(T_bc)
    T_bh = T_floor(0.75, 0.0, math.radians(30))
    T = inv_T(T_bc) @ T_bh @ Geometry().T_humanoid_marker()
    v_true = CAM.project(PTS @ T[:3, :3].T + T[:3, 3])
    rng = np.random.default_rng(1)
    by_image = by_prior = 0
    for _ in range(100):
        v = v_true + rng.normal(0, 0.3, v_true.shape)
        est = estimate_marker_pose(CAM, v, PTS, up_cam=up, sigma_px=0.3)
        assert len(est.candidates) == 2
        angles = [math.degrees(math.acos(np.clip((np.trace(C[:3, :3].T @ T[:3, :3]) - 1) / 2,
                                                 -1, 1))) for C in est.candidates]
        assert max(angles) > 20  # the two branches really differ
        by_image += int(np.argmin(angles) == 0)
        R = est.T_camera_marker[:3, :3]
        by_prior += int(math.degrees(math.acos((np.trace(R.T @ T[:3, :3]) - 1) / 2)) < 10)
    assert by_prior == 100
    assert by_image < 100  # the image alone picks the wrong branch sometimes


@pytest.mark.parametrize("vertices,message", [
    ([[0, 0], [0, 0], [1, 1], [2, 2]], "degenerate"),
    ([[0, 0], [1, 1], [2, 2], [3, 3]], "collinear"),
    ([[np.nan, 0], [1, 0], [1, 1], [0, 1]], "NaN"),
    ([[0, 0], [1, 0]], "need 4 vertices"),
])
def test_degenerate_input_is_rejected_with_a_reason(vertices, message):
    with pytest.raises(PoseError, match=message):
        estimate_marker_pose(CAM, np.array(vertices, float), PTS)


def test_a_pose_behind_the_camera_is_rejected():
    # a crossed quadrilateral: only a plane passing through the camera could project so,
    # which puts some vertices behind it
    q = np.array([[0.822, -1.381], [-2.754, -2.901], [1.88, 2.477], [0.64, 1.377]])
    with pytest.raises(PoseError, match="in front of the camera"):
        ippe(PTS, q)
    px = (CAM.K @ np.column_stack([q, np.ones(4)]).T).T[:, :2]
    with pytest.raises(PoseError, match="in front of the camera"):
        estimate_marker_pose(CAM, px, PTS)


@pytest.fixture(scope="module")
def accuracy():
    cases = pose_cases(1000, seed=7)
    return cases, compare(cases)


def test_accuracy_never_worse_than_the_best_opencv_method_by_2_percent(accuracy):
    _, res = accuracy
    ours_p, ours_a = res["ours (IPPE + upright prior + GN)"]
    for stat in (np.median, lambda a: np.percentile(a, 90)):
        best_p = min(stat(res[k][0]) for k in res if k.startswith("cv2"))
        best_a = min(stat(res[k][1]) for k in res if k.startswith("cv2"))
        assert stat(ours_p) <= 1.02 * best_p, (stat(ours_p), best_p)
        assert stat(ours_a) <= 1.02 * best_a, (stat(ours_a), best_a)


def test_upright_prior_never_loses_a_decidable_branch_at_the_extractors_noise():
    # 0.05-0.3 px is the vertex extractor's measured error (median 0.05, p95 0.27 px)
    cases = pose_cases(1000, seed=9, noise_px=(0.05, 0.3))
    with_prior = wrong_branches(cases)
    assert with_prior.decidable > 200
    assert with_prior.wrong_decidable == 0 and with_prior.search_misses == 0
    image_only = wrong_branches(cases, prior=False)
    assert image_only.wrong_decidable > 0 and with_prior.wrong < image_only.wrong


def test_a_wrong_branch_at_high_noise_is_always_the_posteriors_choice():
    report = wrong_branches(pose_cases(1000, seed=7, noise_px=(0.1, 1.0)))
    assert report.wrong > 0  # at 1 px an upright mirror can fit the image as well as the truth
    assert report.search_misses == 0  # but never because a better mode was missed
    assert report.wrong_decidable <= 0.015 * report.decidable


def test_continuity_prior_keeps_the_branch_through_a_noisy_sequence():
    from services.core.geometry import T_base_camera
    T_bc = T_base_camera(0.0, 0.2, 0.0)  # marker height: mirror branches both level
    up = up_in_camera(T_bc)
    rng = np.random.default_rng(4)
    previous = None
    wrong_alone = wrong_with_history = 0
    for k in range(150):
        T = inv_T(T_bc) @ T_floor(0.7, 0.05, math.radians(25 + 0.05 * k)) @ \
            Geometry().T_humanoid_marker()
        v = CAM.project(PTS @ T[:3, :3].T + T[:3, 3]) + rng.normal(0, 0.5, (4, 2))

        def err(R, T=T):
            return math.degrees(math.acos(np.clip((np.trace(R.T @ T[:3, :3]) - 1) / 2, -1, 1)))
        alone = estimate_marker_pose(CAM, v, PTS, up_cam=up, sigma_px=0.5)
        seq = estimate_marker_pose(CAM, v, PTS, up_cam=up, sigma_px=0.5,
                                   previous_R=T[:3, :3] if previous is None else previous)
        previous = seq.T_camera_marker[:3, :3]
        wrong_alone += int(err(alone.T_camera_marker[:3, :3]) > 20)
        wrong_with_history += int(err(previous) > 20)
    assert wrong_alone > 0 and wrong_with_history == 0


def test_world_pose_composition_and_covariance():
    g = Geometry()
    T_world_base = T_floor(0.1, -0.2, math.radians(20))
    T_world_humanoid = T_floor(0.5, 0.1, math.radians(-35))
    T_world_camera = T_world_base @ g.T_base_camera()
    T_camera_marker = inv_T(T_world_camera) @ T_world_humanoid @ g.T_humanoid_marker()
    (x, y, yaw), cov = humanoid_floor_pose(T_world_camera, T_camera_marker,
                                           inv_T(g.T_humanoid_marker()), np.eye(6) * 1e-6)
    assert (x, y, yaw) == pytest.approx((0.5, 0.1, math.radians(-35)), abs=1e-9)
    assert cov.shape == (3, 3) and np.all(np.linalg.eigvalsh(cov) > 0)


def test_floor_pose_covariance_matches_a_numerical_jacobian():
    from services.core.geometry import floor_pose, make_T
    from services.pose_estimator.p4p import exp_so3
    g = Geometry()
    T_wc = T_floor(0.1, -0.2, math.radians(20)) @ g.T_base_camera()
    T_cm = inv_T(T_wc) @ T_floor(0.5, 0.1, math.radians(-35)) @ g.T_humanoid_marker()
    T_mh = inv_T(g.T_humanoid_marker())
    rng = np.random.default_rng(2)
    A = rng.normal(size=(6, 6))
    cov6 = 1e-6 * A @ A.T
    _, cov = humanoid_floor_pose(T_wc, T_cm, T_mh, cov6)
    J = np.zeros((3, 6))
    base = np.array(floor_pose(T_wc @ T_cm @ T_mh))
    for i in range(6):
        d = np.zeros(6)
        d[i] = 1e-7
        Tp = make_T(exp_so3(d[:3]) @ T_cm[:3, :3], T_cm[:3, 3] + d[3:])
        J[:, i] = (np.array(floor_pose(T_wc @ Tp @ T_mh)) - base) / 1e-7
    assert np.allclose(cov, J @ cov6 @ J.T, rtol=1e-5, atol=1e-14)


def test_service_publishes_world_pose_and_nulls_without_odometry(router, make_bus, tmp_path):
    g = Geometry()
    dep = parse_deployment({"zenoh": {"connect": [router], "multicast_scouting": False},
                            "services": {"pose_estimator": {"intrinsics": "cam.toml"}}},
                           tmp_path / "dep.toml")
    (tmp_path / "cam.toml").write_text(CAM.to_toml())
    T_world_base = T_floor(0.0, 0.0, 0.0)
    T_camera_marker = inv_T(T_world_base @ g.T_base_camera()) @ T_floor(0.4, 0.02, 0.1) @ \
        g.T_humanoid_marker()
    v = CAM.project(PTS @ T_camera_marker[:3, :3].T + T_camera_marker[:3, 3])
    bus = make_bus("feeder")

    def vertices(seq, stamp):
        return MarkerVertices(seq=seq, stamp_ns=stamp, found=True,
                              vertices_px=tuple(map(tuple, v)), width=640, height=480)

    async def go():
        poses = bus.subscribe(HUMANOID_POSE, HumanoidPose, latest=False, queue=16)
        steady = bus.subscribe(HUMANOID_POSE_FILTERED, HumanoidPose, latest=False, queue=16)
        task = asyncio.create_task(run_deployment(dep, duration=60))
        await wait_alive_async(bus.session, "pose_estimator")
        bus.put(VERTICES, vertices(1, 10**18))
        p1 = await poses.recv(timeout=30)
        assert p1.x is None and "odometry" in p1.reason
        assert p1.marker_in_camera.position[2] == pytest.approx(T_camera_marker[2, 3], abs=1e-6)
        bus.put(ODOM, CameraPose(stamp_ns=2 * 10**18, x=0.0, y=0.0, yaw=0.0))
        # not observable from here: without this wait the vertices, published after the
        # odometry, sometimes reach the estimator first (seen 1 in 7 runs on a loaded machine)
        await asyncio.sleep(0.2)
        bus.put(VERTICES, vertices(2, 2 * 10**18))
        p2 = await poses.recv(timeout=30)
        assert (p2.x, p2.y, p2.yaw) == pytest.approx((0.4, 0.02, 0.1), abs=1e-6)
        assert p2.covariance is not None
        s2 = await steady.recv(timeout=30)  # the steady pose, beside it, starts there
        assert (s2.seq, s2.x, s2.y) == (2, pytest.approx(0.4, abs=1e-6), pytest.approx(0.02))
        assert s2.covariance is not None and s2.covariance[0][0] > p2.covariance[0][0]
        bad = MarkerVertices(seq=3, stamp_ns=1, found=True,
                             vertices_px=((1, 1), (1, 1), (1, 1), (1, 1)))
        bus.put(VERTICES, bad)  # degenerate: logged, no pose, service stays up
        bus.put(VERTICES, vertices(4, 2 * 10**18))
        p4 = await poses.recv(timeout=30)
        assert p4.seq == 4
        task.cancel()
    asyncio.run(go())


def test_odometry_is_interpolated_at_the_frame_stamp_and_held_only_near_it():
    from services.pose_estimator.odometry import OdometryBuffer
    buf = OdometryBuffer(maxlen=4)
    assert buf.at(5, 0.5) == (None, "no camera odometry received")
    for stamp, yaw in ((30, -3.0), (10, 3.0), (20, 3.1), (40, -2.9)):  # out of order on purpose
        buf.add(CameraPose(stamp_ns=stamp * 10**8, x=stamp / 10, y=0.0, yaw=yaw))
    assert [o.stamp_ns for o in buf.samples] == [10**9, 2 * 10**9, 3 * 10**9, 4 * 10**9]
    (x, _, yaw), why = buf.at(25 * 10**8, 0.5)  # halfway from yaw 3.1 to -3.0, across +-pi
    assert why == "" and x == pytest.approx(2.5)
    assert yaw == pytest.approx(math.remainder(3.1 + 0.5 * (2 * math.pi - 6.1), 2 * math.pi))
    assert buf.at(3 * 10**9, 0.5)[0] == (3.0, 0.0, -3.0)  # an exact stamp is the sample itself
    assert buf.at(43 * 10**8, 0.5)[0] == (4.0, 0.0, -2.9)  # newer than all: the newest, held
    assert "1.00 s from the frame" in buf.at(5 * 10**9, 0.5)[1]
    assert buf.covers(4 * 10**9) and not buf.covers(4 * 10**9 + 1)
    buf.add(CameraPose(stamp_ns=15 * 10**8, x=1.5, y=0.0, yaw=0.0))  # full: the oldest goes
    assert [o.stamp_ns // 10**8 for o in buf.samples] == [15, 20, 30, 40]


def test_service_waits_briefly_for_odometry_that_trails_the_vertices():

    class Mailbox:
        def __init__(self):
            self.queue: asyncio.Queue = asyncio.Queue()
            self.waits = 0

        def get_nowait(self):
            return None if self.queue.empty() else self.queue.get_nowait()

        async def recv(self, timeout=None):
            self.waits += 1
            return await asyncio.wait_for(self.queue.get(), timeout)

    est = svc.PoseEstimator(CAM, Geometry(), svc.Settings())
    odom = Mailbox()

    async def go():
        asyncio.get_running_loop().call_later(
            0.01, odom.queue.put_nowait, CameraPose(stamp_ns=100, x=0.3, y=0.0, yaw=0.0))
        await svc.await_odometry(est, odom, 100, wait_s=1.0)  # arrives 10 ms later: taken
        assert est.odom.at(100, 0.5)[0] == (0.3, 0.0, 0.0) and not est.odom_stalled
        await svc.await_odometry(est, odom, 200, wait_s=0.05)  # never comes: gives up once
        assert est.odom_stalled
        waits = odom.waits
        await svc.await_odometry(est, odom, 300, wait_s=0.05)  # still none: no second wait
        assert odom.waits == waits
        odom.queue.put_nowait(CameraPose(stamp_ns=400, x=0.4, y=0.0, yaw=0.0))
        await svc.await_odometry(est, odom, 400, wait_s=0.05)
        assert not est.odom_stalled and est.odom.covers(400)
    asyncio.run(go())


def test_service_uses_its_tilt_prior_setting(monkeypatch):
    seen: dict = {}
    from services.pose_estimator import sequence
    original = sequence.estimate_marker_pose

    def spy(*args, **kwargs):
        seen.update(kwargs)
        return original(*args, **kwargs)
    monkeypatch.setattr(sequence, "estimate_marker_pose", spy)
    est = svc.PoseEstimator(CAM, Geometry(), svc.Settings(tilt_sigma_deg=1.5,
                                                          static_camera_pose=(0.0, 0.0, 0.0)))
    T = marker_pose(0.4, 320, 240, CAM)
    v = CAM.project(PTS @ T[:3, :3].T + T[:3, 3])
    pose = est.estimate(MarkerVertices(seq=1, stamp_ns=1, found=True, width=640, height=480,
                                       vertices_px=tuple(map(tuple, v))))
    assert pose.x is not None
    assert seen["tilt_sigma_rad"] == pytest.approx(math.radians(1.5))


def test_camera_model_refuses_distortion_it_cannot_represent():
    K = CAM.K
    assert CameraModel(K, [-0.2, 0.1]).dist.tolist() == [-0.2, 0.1, 0.0, 0.0, 0.0]
    assert CameraModel(K, [-0.2, 0.1, 0, 0, 0.01, 0, 0, 0]).dist[4] == 0.01
    with pytest.raises(ValueError, match="8 coefficients"):
        CameraModel(K, [-0.2, 0.1, 0, 0, 0.01, 0.3, 0, 0])
    with pytest.raises(ValueError, match="3x3"):
        CameraModel(np.eye(2))


_px = st.sampled_from([0.0, 1e-9, 319.5, -1e6, 1e6, 1e300, -1e300, 5e-324]) | st.floats(
    -1e4, 1e4)


@st.composite
def _hostile_vertices(draw: st.DrawFn) -> list[tuple[float, float]]:
    kind = draw(st.sampled_from(["coincident", "collinear", "tiny", "huge", "any"]))
    if kind == "coincident":
        return [(draw(_px), draw(_px))] * 4
    if kind == "collinear":
        a, d = draw(_px), draw(st.floats(-1e3, 1e3))
        return [(a + k * d, 2 * a - k * d) for k in range(4)]
    if kind == "tiny":
        u, v, e = draw(st.floats(0, 640)), draw(st.floats(0, 480)), draw(
            st.sampled_from([1e-12, 1e-9, 1e-6]))
        return [(u - e, v), (u, v - e), (u + e, v), (u, v + e)]
    if kind == "huge":
        e = draw(st.sampled_from([1e6, 1e12, 1e300]))
        return [(-e, 0.0), (0.0, -e), (e, 0.0), (0.0, e)]
    return [(draw(_px), draw(_px)) for _ in range(4)]


@settings(max_examples=400, deadline=None)
@given(_hostile_vertices(), st.integers(0, 2**70), st.booleans())
def test_hostile_vertices_give_a_pose_or_a_reason_never_a_crash(vertices, stamp, moving):
    """Every schema-valid vertex set is a valid pose message or a PoseError with a reason."""
    est = svc.PoseEstimator(CAM, Geometry(), svc.Settings(
        static_camera_pose=None if moving else (0.0, 0.0, 0.0)))
    est.odom.add(CameraPose(stamp_ns=stamp, x=1e4, y=-1e4, yaw=1e300))
    msg = MarkerVertices(seq=1, stamp_ns=stamp, found=True, vertices_px=tuple(vertices),
                         width=640, height=480)
    try:
        pose = est.estimate(msg)
    except PoseError as err:
        assert str(err)
        return
    assert HumanoidPose.model_validate_json(pose.model_dump_json()) == pose


def test_the_steady_pose_damps_the_gaits_sway_and_settles_where_the_humanoid_stops():
    from services.pose_estimator.pose_filter import PoseFilter
    f = PoseFilter()
    rng = np.random.default_rng(4)
    raw, steady, truth = [], [], []
    for k in range(300):  # 6 s walking at 6.7 cm/s, then 4 s standing
        t = k / 30
        x = 0.3 + 0.067 * min(t, 6.0)
        sway = 0.004 * math.sin(math.pi * t / 0.6) if t < 6.0 else 0.0  # the marker's rock
        z = (x + 5e-4 * rng.standard_normal(), sway + 5e-4 * rng.standard_normal(), 0.0)
        out, P = f.update(int(t * 1e9), z, np.diag([2.5e-7, 2.5e-7, 1e-4]))
        raw.append(z)
        steady.append(out)
        truth.append(x)
    raw_a, steady_a = np.array(raw), np.array(steady)
    walking = slice(60, 170)
    assert steady_a[walking, 1].std() < 0.75 * raw_a[walking, 1].std()
    assert abs(steady_a[-1, 0] - truth[-1]) < 1e-3 and abs(steady_a[-1, 1]) < 1e-3
    assert np.all(np.linalg.eigvalsh(P) > 0) and f.restarts == 0


def test_the_steady_pose_restarts_on_a_jump_and_wraps_heading():
    from services.pose_estimator.pose_filter import PoseFilter
    f = PoseFilter()
    for k in range(10):
        f.update(k * 33_000_000, (0.5, 0.0, math.pi - 0.01), None)
    out, _ = f.update(10 * 33_000_000, (0.5, 0.0, -math.pi + 0.01), None)  # across ±pi
    assert abs(out[2]) > math.pi - 0.02 and f.restarts == 0
    out, _ = f.update(11 * 33_000_000, (0.9, 0.3, 0.0), None)  # found elsewhere: restart
    assert tuple(out) == (0.9, 0.3, 0.0) and f.restarts == 1
    f.update(5 * 33_000_000, (0.9, 0.3, 0.0), None)  # a stamp going back: restart
    assert f.restarts == 2


def _walk(phi_deg: float, x0: float, seed: int, n: int = 90, sigma_px: float = 0.4
          ) -> list[tuple[int, np.ndarray, float, np.ndarray]]:
    """Frames of the humanoid walking at ``phi_deg`` to the line of sight from ``x0`` m away,
    the camera at the marker's height (yaw mirrors): (stamp, noisy vertices, yaw, T)."""
    g = Geometry()
    T_bc = g.T_base_camera()
    rng = np.random.default_rng(seed)
    yaw = math.radians(phi_deg)
    out = []
    for k in range(n):
        t = k / 30
        x, y = x0 + 0.067 * t * math.cos(yaw), -0.02 + 0.067 * t * math.sin(yaw)
        T = inv_T(T_bc) @ T_floor(x, y, yaw) @ g.T_humanoid_marker()
        v = CAM.project(PTS @ T[:3, :3].T + T[:3, 3]) + rng.normal(0, sigma_px, (4, 2))
        out.append((int(1e12 + t * 1e9), v, yaw, T))
    return out


def _yaw_errors(est: svc.PoseEstimator, frames: list) -> np.ndarray:
    out = []
    for k, (stamp, v, yaw, _) in enumerate(frames):
        p = est.estimate(MarkerVertices(seq=k, stamp_ns=stamp, found=True, vertices_px=(
            (v[0, 0], v[0, 1]), (v[1, 0], v[1, 1]), (v[2, 0], v[2, 1]), (v[3, 0], v[3, 1])),
            width=640, height=480))
        assert p.yaw is not None
        out.append(abs(math.degrees(math.atan2(math.sin(p.yaw - yaw), math.cos(p.yaw - yaw)))))
    return np.array(out)


@pytest.mark.parametrize("start_on_mirror", [False, True])
def test_sequences_starting_on_either_branch_converge_to_the_truth(start_on_mirror: bool):
    """Within 30 frames (1 s) the estimator follows the true branch, whichever it started on;
    while the branches are not yet separated its poses say they are ambiguous."""
    from services.pose_estimator.estimate import estimate_marker_pose
    late_wrong = 0
    for seed in range(3):
        for phi, x0 in ((18.0, 0.6), (18.0, 0.75), (25.0, 0.8)):
            frames = _walk(phi, x0, seed)
            est = svc.PoseEstimator(CAM, Geometry(), svc.Settings(
                static_camera_pose=(0.0, 0.0, 0.0)))
            if start_on_mirror:  # the tracks begin believing the mirror
                stamp, v, _, T = frames[0]
                cands = estimate_marker_pose(CAM, v, PTS, up_cam=est.up_cam).candidates
                mirror = max(cands, key=lambda c: np.linalg.norm(c[:3, :3] - T[:3, :3]))
                true = min(cands, key=lambda c: np.linalg.norm(c[:3, :3] - T[:3, :3]))
                est.sequence.branches.update([(mirror[:3, :3], 0.0), (true[:3, :3], 30.0)],
                                             T[:3, 3])
                est.sequence.previous = (stamp - 33_000_000, mirror[:3, :3])
            errors = _yaw_errors(est, frames)
            late_wrong += int(np.sum(errors[30:] > 10.0))
    assert late_wrong <= 0.015 * 9 * 60, late_wrong  # of the frames after the first second


def test_the_branch_tracker_halves_wrong_branch_frames_on_hard_sequences():
    """Far, nearly face-on, 0.4 px noise: a single frame's choice flips with the noise."""
    tracked = 0
    single = 0
    for seed in range(3):
        for phi, x0 in ((10.0, 0.6), (14.0, 0.75)):
            frames = _walk(phi, x0, seed)
            est = svc.PoseEstimator(CAM, Geometry(), svc.Settings(
                static_camera_pose=(0.0, 0.0, 0.0)))
            tracked += int(np.sum(_yaw_errors(est, frames) > 10.0))
            single += sum(int(_yaw_errors(svc.PoseEstimator(CAM, Geometry(), svc.Settings(
                static_camera_pose=(0.0, 0.0, 0.0))), [f]).item() > 10.0) for f in frames)
    assert tracked <= 0.5 * single, (tracked, single)


def test_unrelated_views_pay_nothing_for_continuity_and_branch_tracking():
    """Independent views 33 ms apart (the tracks restart when the marker jumps) are estimated
    as well as the same views a second apart (no prior from the previous frame)."""
    g = Geometry()
    T_bc = g.T_base_camera()
    rng = np.random.default_rng(11)
    views = []
    while len(views) < 200:
        dist, bearing = rng.uniform(0.15, 0.8), rng.uniform(-0.3, 0.3)
        yaw = bearing + math.radians(rng.uniform(-40, 40))
        mx, my = dist * math.cos(bearing), dist * math.sin(bearing)
        T = inv_T(T_bc) @ T_floor(mx + 0.05 * math.cos(yaw), my + 0.05 * math.sin(yaw), yaw) \
            @ g.T_humanoid_marker()
        v = CAM.project(PTS @ T[:3, :3].T + T[:3, 3])
        if T[2, 3] > 0.1 and np.all(v > 5) and np.all(v < [634, 474]):
            views.append((T, v + rng.normal(0, 0.3, v.shape)))

    def errors(gap_ns: int) -> np.ndarray:
        est = svc.PoseEstimator(CAM, g, svc.Settings(static_camera_pose=(0.0, 0.0, 0.0)))
        out = []
        for k, (T, v) in enumerate(views):
            p = est.estimate(MarkerVertices(
                seq=k, stamp_ns=10**12 + k * gap_ns, found=True, width=640, height=480,
                vertices_px=((v[0, 0], v[0, 1]), (v[1, 0], v[1, 1]), (v[2, 0], v[2, 1]),
                             (v[3, 0], v[3, 1]))))
            out.append(np.linalg.norm(np.array(p.marker_in_camera.position) - T[:3, 3]))
        return np.array(out)
    close, apart = errors(33_000_000), errors(10**9)
    assert np.mean(close != apart) <= 0.02  # the same estimate on (almost) every view
    assert close.mean() <= 1.01 * apart.mean()


def _sway_walk(fps: float, seed: int, sway_deg: float, noise_px: float, scale_px: float
               ) -> list[tuple[int, np.ndarray, float]]:
    """Walking straight away 30-60 cm from a camera at the marker's height, the heading
    swaying across the line of sight: (stamp, noisy vertices, true heading in the camera)."""
    from services.tools.pose_sequences import walk_away
    g = Geometry()
    rng = np.random.default_rng(seed)
    out = []
    for k, (x, y, yaw, _) in enumerate(walk_away(fps, seed, sway_deg, 0.3, 0.6).truth):
        T = inv_T(g.T_base_camera()) @ T_floor(x, y, yaw) @ g.T_humanoid_marker()
        v = CAM.project(PTS @ T[:3, :3].T + T[:3, 3])
        v = v + rng.normal(0, noise_px, v.shape) + rng.normal(0, scale_px) * (v - v.mean(0)) \
            / np.linalg.norm(v - v.mean(0)) * 2
        out.append((int(1e12 + k * 1e9 / fps), v, yaw))
    return out


@pytest.mark.parametrize("fps", [30.0, 15.0])
def test_the_sequence_holds_the_heading_through_face_on_crossings(fps: float):
    """No bus: the sequence logic alone, on a walk whose heading crosses the line of sight
    every step. Never a confident wrong branch; the errors small; the NEES near 3."""
    from services.pose_estimator.sequence import MarkerSequence
    g = Geometry()
    errors, sigmas, ambiguous, nees = [], [], [], []
    for seed, sway in ((0, 2.0), (1, 4.0), (2, 6.0)):
        seq = MarkerSequence(CAM, PTS, up_in_camera(g.T_base_camera()))
        for stamp, v, yaw in _sway_walk(fps, seed, sway, 0.03, 0.1):
            est = seq.update(stamp, v)
            (_, _, yaw_est), P = humanoid_floor_pose(
                g.T_base_camera(), est.T_camera_marker, inv_T(g.T_humanoid_marker()),
                est.covariance)
            assert P is not None
            e = math.remainder(yaw_est - yaw, 2 * math.pi)
            errors.append(math.degrees(e))
            sigmas.append(math.degrees(math.sqrt(P[2, 2])))
            ambiguous.append(est.ambiguous and "ambiguous" in est.reason)
            nees.append(e * e / P[2, 2])
    err, sig, amb = np.abs(errors), np.array(sigmas), np.array(ambiguous)
    assert np.median(err) <= 0.5 and np.percentile(err, 95) <= 2.0, (np.median(err),
                                                                     np.percentile(err, 95))
    assert not np.any((err > 5.0) & ~(amb & (err <= 3 * sig)))
    assert 0.3 <= np.mean(nees) <= 1.5, np.mean(nees)  # yaw alone: chi-squared, 1 dof


def test_extractor_vertex_covariance_is_used_when_present():
    from services.pose_estimator.sequence import MarkerSequence
    g = Geometry()
    stamp, v, _ = _sway_walk(30.0, 0, 4.0, 0.0, 0.0)[60]
    seq = MarkerSequence(CAM, PTS, up_in_camera(g.T_base_camera()))
    fixed = seq.update(stamp, v).covariance
    seq.reset()
    loose = seq.update(stamp, v, [[[0.25, 0.0], [0.0, 0.25]]] * 4).covariance
    assert np.trace(loose[:3, :3]) > 4 * np.trace(fixed[:3, :3])


@pytest.mark.slow
def test_webcam_sequences_at_the_marker_height_meet_the_heading_and_covariance_goals():
    """Walking away 15-60 cm (sway ±4°, 30 and 15 fps), turning in place to ±30° and random
    nearby poses, rendered through the simulated webcam and the extractor."""
    from services.data import SIM_CAMERA
    from services.tools import pose_sequences as ps
    nees = []
    for i, (seq, jpeg) in enumerate(ps.standard_sequences(quick=True)):
        est = svc.PoseEstimator(CameraModel.load(SIM_CAMERA), Geometry(), svc.Settings(
            static_camera_pose=(0.0, 0.0, 0.0)))
        sc = ps.track(ps.render(seq, seed=i, jpeg=jpeg), est.estimate)
        err = np.abs(sc.heading_err_deg)
        assert len(err) >= 0.9 * sc.frames
        assert est.sequence.mount_d is None  # a correct mount is never corrected
        assert sc.bad(5.0) == 0, seq.name
        if seq.name.startswith("walk"):
            assert np.median(err) <= 0.5 and np.percentile(err, 95) <= 2.0, seq.name
            assert np.percentile(sc.position_err_m, 95) <= 0.006, seq.name
        nees.append(sc.nees)
    assert 2.0 <= np.nanmean(np.concatenate(nees)) <= 4.5


def test_a_mount_pitched_off_the_deployment_file_is_detected_and_told():
    """The camera really pitched 8° down, the file says level: the sequence estimates the
    offset from the marker's mean lean and the service says so, and again once it corrects
    the up with it."""
    from services.core.geometry import T_base_camera
    from services.tools.pose_sequences import turn_in_place
    g = Geometry()
    est = svc.PoseEstimator(CAM, g, svc.Settings(static_camera_pose=(0.0, 0.0, 0.0)))
    T_real = T_base_camera(g.camera_forward_m, g.camera_height_m, math.radians(8.0))
    rng = np.random.default_rng(0)
    told = []
    for k, (x, y, yaw, _) in enumerate(turn_in_place(30.0, 0).truth):
        T = inv_T(T_real) @ T_floor(x, y, yaw) @ g.T_humanoid_marker()
        v = CAM.project(PTS @ T[:3, :3].T + T[:3, 3]) + rng.normal(0, 0.05, (4, 2))
        est.estimate(MarkerVertices(seq=k, stamp_ns=10**12 + k * 33_000_000, found=True,
                                    vertices_px=tuple(map(tuple, v))))  # type: ignore[arg-type]
        if warning := est.mount_warning():
            told.append(warning)
    assert len(told) == 2 and all("pitched +" in t for t in told), told  # then quiet
    assert "not corrected" in told[0] and "uses the estimated up" in told[1]
    off = est.sequence.mount.offset_deg() if est.sequence.mount else None
    assert off is not None and abs(off[0] - 8.0) < 1.0 and abs(off[1]) < 1.0
    level = svc.PoseEstimator(CAM, g, svc.Settings(static_camera_pose=(0.0, 0.0, 0.0)))
    for k, (_, v, _) in enumerate(_sway_walk(30.0, 0, 4.0, 0.05, 0.0)):
        level.estimate(MarkerVertices(seq=k, stamp_ns=10**12 + k * 33_000_000, found=True,
                                      vertices_px=tuple(map(tuple, v))))  # type: ignore[arg-type]
        assert level.mount_warning() == ""


def test_a_face_on_walk_with_the_mount_pitched_off_settles_the_correction():
    """Walking straight away, face-on, the camera really pitched 8° down: the marker's lean
    pins the pitch (its roll, unseen face-on, no longer holds the check back) and the
    sequence corrects the up; from then the floor position is right (the lever to the feet
    through the true vertical)."""
    from services.core.geometry import T_base_camera
    from services.tools.pose_sequences import walk_away
    g = Geometry()
    est = svc.PoseEstimator(CAM, g, svc.Settings(static_camera_pose=(0.0, 0.0, 0.0)))
    T_real = T_base_camera(g.camera_forward_m, g.camera_height_m, math.radians(8.0))
    rng = np.random.default_rng(3)
    errors, corrected = [], []
    for k, (x, y, yaw, _) in enumerate(walk_away(30.0, 0, 4.0, 0.2, 0.6).truth):
        T = inv_T(T_real) @ T_floor(x, y, yaw) @ g.T_humanoid_marker()
        v = CAM.project(PTS @ T[:3, :3].T + T[:3, 3]) + rng.normal(0, 0.05, (4, 2))
        pose = est.estimate(MarkerVertices(seq=k, stamp_ns=10**12 + k * 33_000_000, found=True,
                                           vertices_px=tuple(map(tuple, v))))  # type: ignore[arg-type]
        assert pose.x is not None and pose.y is not None
        errors.append(math.hypot(pose.x - x, pose.y - y))
        corrected.append(est.sequence.mount_d is not None)
    on = np.array(corrected)
    assert on.any() and on[np.argmax(on):].all()  # settles, then stays
    settled = int(np.argmax(on))
    assert settled <= 60
    assert np.percentile(np.array(errors)[on], 95) < 0.006
    assert np.percentile(np.array(errors)[:settled], 50) > 0.02  # what it costs before


def test_the_tested_upright_prior_gains_on_upright_views_and_costs_nothing_when_wrong():
    """Unrelated views at 0.3 px against OpenCV's IPPE on the same vertices (two seeds
    pooled: one seed's p90 moves by ±3 %): upright markers better; markers pitched to 15°
    and rolled to 10° no worse (a Gaussian prior would pay there); a mount 8° off the
    file's better too (the marker's elevation gives the prior the real vertical)."""
    from services.pose_estimator.evaluate import ippe_errors, ippe_ratios, unrelated_views

    def pooled(lean_deg: float = 3.0, roll_deg: float = 0.0, mount_off_deg: float = 0.0
               ) -> list:
        return [c for seed in (5, 6) for c in unrelated_views(
            700, seed, lean_deg=lean_deg, roll_deg=roll_deg, mount_off_deg=mount_off_deg)]

    upright = ippe_ratios(*ippe_errors(pooled()))
    assert upright[0] <= 0.95 and upright[1] <= 1.0, upright
    tilted_views = pooled(lean_deg=15.0, roll_deg=10.0)
    tilted = ippe_ratios(*ippe_errors(tilted_views))
    gaussian = ippe_ratios(*ippe_errors(tilted_views, tilt_huber_sigmas=0.0,
                                        upright_probability=1.0))
    assert tilted[0] <= 1.05 and tilted[1] <= 1.02, tilted
    assert gaussian[1] > tilted[1] + 0.05  # what the test and the heavy tails save
    mount_views = pooled(lean_deg=2.0, mount_off_deg=8.0)
    mount = ippe_ratios(*ippe_errors(mount_views))
    assert mount[0] <= 0.98 and mount[1] <= 1.0, mount
    file_up = ippe_ratios(*ippe_errors(mount_views, height_m=None))  # type: ignore[arg-type]
    assert file_up[0] > mount[0] + 0.02  # what the elevation saves


def test_the_marker_elevation_finds_a_mount_pitched_off_the_file():
    """A camera really pitched 8° down (the file says level) sees the marker at its own
    height 8° above the optical axis: the elevation's up takes most of the offset (the
    blend with the file keeps 8 % of it at 20 cm, 1 % at 60 cm); a level mount's is left
    where it is."""
    from services.core.geometry import T_base_camera
    from services.pose_estimator.estimate import up_from_elevation
    g = Geometry()
    up_file = up_in_camera(g.T_base_camera())
    for pitch_deg in (8.0, -8.0, 0.0):
        T_real = T_base_camera(g.camera_forward_m, g.camera_height_m, math.radians(pitch_deg))
        up_true = up_in_camera(T_real)
        for distance in (0.2, 0.6):
            T = inv_T(T_real) @ T_floor(distance, 0.02, 0.3) @ g.T_humanoid_marker()
            up, sigma = up_from_elevation(up_file, T[:3, 3], 0.0)
            err = math.degrees(math.acos(min(1.0, float(up @ up_true))))
            assert err < 0.15 * abs(pitch_deg) + 0.1, (pitch_deg, distance, err)
            assert sigma < math.radians(2.0)


def test_a_turn_across_the_line_of_sight_far_away_never_leaves_a_confident_mirror():
    """68 cm away, 10° off the axis, turning right through the line of sight: the branches
    meet and part again; the evidence from before the meeting must not carry a track onto
    the mirror (it did: 29° off with a sigma under 1°)."""
    from services.pose_estimator.sequence import MarkerSequence
    g = Geometry()
    worst, uncovered = 0.0, 0
    for seed in range(6):
        rng = np.random.default_rng(seed)
        seq = MarkerSequence(CAM, PTS, up_in_camera(g.T_base_camera()))
        for k in range(75):
            yaw = math.radians(25 - 40 * k / 75 + rng.normal(0, 0.3))
            T = inv_T(g.T_base_camera()) @ T_floor(0.68, 0.12, yaw) @ g.T_humanoid_marker()
            v = CAM.project(PTS @ T[:3, :3].T + T[:3, 3])
            v = v + rng.normal(0, 0.04, v.shape) + rng.normal(0, 0.1) * 2 * \
                (v - v.mean(0)) / np.linalg.norm(v - v.mean(0))
            est = seq.update(int(1e12 + k * 33_333_333), v)
            (_, _, yaw_est), P = humanoid_floor_pose(
                g.T_base_camera(), est.T_camera_marker, inv_T(g.T_humanoid_marker()),
                est.covariance)
            assert P is not None
            e = abs(math.degrees(math.remainder(yaw_est - yaw, 2 * math.pi)))
            worst = max(worst, e)
            uncovered += int(e > 5 and not (est.ambiguous and e <= math.degrees(
                math.sqrt(P[2, 2]))))
    assert uncovered == 0 and worst < 10.0, (uncovered, worst)


def _mount_run(off_deg: float, correction: bool, frames: int = 180, seed: int = 0,
               then_off_deg: float | None = None
               ) -> tuple[np.ndarray, np.ndarray, list[bool], object]:
    """No bus: the sequence turning in place (35 cm, ±30°) before a camera whose real mount
    is pitched ``off_deg`` off the file's (``then_off_deg`` from the middle on); the world
    pose composed through the file's mount and the sequence's correction. (position errors
    m, heading errors deg, correcting per frame, the sequence)."""
    from services.core.geometry import T_base_camera, make_T
    from services.pose_estimator.sequence import MarkerSequence, SequenceParams
    from services.tools.pose_sequences import turn_in_place
    g = Geometry()
    T_file = g.T_base_camera()
    seq = MarkerSequence(CAM, PTS, up_in_camera(T_file),
                         SequenceParams(mount_correction=correction))
    rng = np.random.default_rng(seed)
    truth = turn_in_place(30.0, seed, seconds=frames / 30.0).truth
    pos, head, correcting = [], [], []
    for k, (x, y, yaw, _) in enumerate(truth):
        off = off_deg if then_off_deg is None or k < len(truth) // 2 else then_off_deg
        T_real = T_base_camera(g.camera_forward_m, g.camera_height_m,
                               g.camera_pitch_rad + math.radians(off))
        T = inv_T(T_real) @ T_floor(x, y, yaw) @ g.T_humanoid_marker()
        v = CAM.project(PTS @ T[:3, :3].T + T[:3, 3]) + rng.normal(0, 0.05, (4, 2))
        est = seq.update(int(1e12 + k * 33_333_333), v)
        T_world_camera = T_file @ make_T(seq.R_mount_correction.T, (0.0, 0.0, 0.0))
        (xe, ye, yawe), _ = humanoid_floor_pose(T_world_camera, est.T_camera_marker,
                                                inv_T(g.T_humanoid_marker()))
        pos.append(math.hypot(xe - x, ye - y))
        head.append(math.degrees(math.remainder(yawe - yaw, 2 * math.pi)))
        correcting.append(seq.mount_d is not None)
    return np.array(pos), np.array(head), correcting, seq


def test_a_mount_pitched_8_degrees_off_is_corrected_once_the_check_has_settled():
    """The real mount pitched 8° down, the file level: without the correction the marker-
    to-feet lever goes through the wrong vertical (about 25 mm off); once the check has
    settled, the up it found puts the world position back within a few mm."""
    pos, head, correcting, seq = _mount_run(8.0, True)
    before, _, never, _ = _mount_run(8.0, False)
    assert not any(never)
    settled = correcting.index(True)
    assert 30 <= settled <= 120 and all(correcting[settled:])  # settles and stays
    late = slice(settled + 10, None)
    assert np.percentile(before[late], 95) > 0.015
    assert np.percentile(pos[late], 95) < 0.005, np.percentile(pos[late], 95)
    assert np.percentile(np.abs(head[late]), 95) < 1.0
    assert seq.mount_d is not None and abs(math.degrees(seq.mount_d[0]) - 8.0) < 1.0


def test_a_correct_mount_is_never_corrected_and_its_poses_are_unchanged():
    """The mount as the file says: the correction stays off, every pose identical to the
    sequence without it."""
    pos, head, correcting, seq = _mount_run(0.0, True)
    pos_off, head_off, _, _ = _mount_run(0.0, False)
    assert not any(correcting)
    assert seq.mount is not None and (seq.mount.offset_deg() is not None)
    assert np.array_equal(pos, pos_off) and np.array_equal(head, head_off)


def test_the_mount_correction_resets_when_the_evidence_changes():
    """8° off for 240 frames, then the camera set right (a new mount): the check sees the
    last frames' lean disagree, restarts, and the correction goes off again."""
    pos, _, correcting, seq = _mount_run(8.0, True, frames=480, then_off_deg=0.0)
    assert correcting[200] and not correcting[-1]
    assert seq.mount is not None and seq.mount.resets >= 1
    assert np.percentile(pos[-60:], 95) < 0.005
