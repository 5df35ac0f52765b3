"""The simulator's webcam, and the marker found and measured through it: default colour model,
learned inks (``shepherd marker learn`` / ``colour_file``), no markers in photographs."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from services.core.camera import CameraModel
from services.core.mounts import Geometry
from services.runtime.config import ConfigError, parse_deployment
from services.sim import textures
from services.sim.render import INKS_BGR, render_view
from services.sim.scenes import marker_pose, random_views, random_webcam
from services.sim.webcam import WebcamParams, expose, linear_to_srgb, srgb_to_linear
from services.vertex_extractor.colour import ColourModel
from services.vertex_extractor.extractor import ExtractorParams, RhombusExtractor
from services.vertex_extractor.learn import LearnError, learn, write_colour_file
from tests.conftest import cli_here

pytestmark = pytest.mark.skipif(not textures.have_photos(),
                                reason="scikit-image (dev extra) ships the photographs")


def _errors(ink: str, params: ExtractorParams, n: int = 60, seed: int = 7
            ) -> tuple[np.ndarray, int, int]:
    ex = RhombusExtractor(params)
    errors, found, total = [], 0, 0
    for v in random_views(n, seed=seed, webcam=True, ink=ink, distance_m=(0.2, 0.8)):
        r = v.rendered
        if not r.marker_visible or r.coverage_area_px < 200:
            continue
        total += 1
        ex.reset()
        det = ex.extract(r.image)
        if det.found and det.vertices_px is not None and r.vertices_px is not None:
            found += 1
            errors.append(np.linalg.norm(det.vertices_px - r.vertices_px, axis=1))
    return np.concatenate(errors), found, total


def _photographs(n: int = 20) -> list[np.ndarray]:
    rng = np.random.default_rng(99)
    return [expose(textures.photograph(640, 480, s), random_webcam(rng), rng) for s in range(n)]


def _learned(ink: str) -> ColourModel:
    images = [(f"{ink}{i}", v.rendered.image) for i, v in enumerate(
        random_views(4, seed=21, webcam=True, ink=ink, distance_m=(0.25, 0.5)))]
    model, report = learn(images)
    assert all(s.recall > 0.95 and s.false_rate < 0.002 for s in report)
    return model


def test_every_stage_off_is_the_srgb_encoding_of_the_scene():
    scene = np.random.default_rng(0).uniform(0, 1, (40, 60, 3)).astype(np.float32)
    off = WebcamParams(exposure=1.0, blur_sigma_px=0, bayer=False, shot_noise=False,
                       read_noise_e=0, jpeg_quality=0)
    out = expose(scene, off, np.random.default_rng(0))
    assert np.abs(out.astype(float) - 255 * linear_to_srgb(scene)).max() <= 0.6  # via 16 bits
    assert np.allclose(srgb_to_linear(linear_to_srgb(scene)), scene, atol=1e-5)


def test_bayer_demosaic_keeps_a_flat_colour_and_noise_scales_with_light():
    flat = np.empty((64, 64, 3), np.float32)
    flat[:] = srgb_to_linear(np.array(INKS_BGR["process"]) / 255.0)
    mosaic = WebcamParams(exposure=1.0, blur_sigma_px=0, shot_noise=False, read_noise_e=0,
                          jpeg_quality=0)
    out = expose(flat, mosaic, np.random.default_rng(0))
    assert np.abs(out[8:-8, 8:-8].astype(int) - INKS_BGR["process"]).max() <= 1
    noisy = WebcamParams(blur_sigma_px=0, bayer=False, jpeg_quality=0, full_well_e=1000)
    dark = expose(np.full((64, 64, 3), 0.05, np.float32), noisy, np.random.default_rng(1))
    bright = expose(np.full((64, 64, 3), 0.5, np.float32), noisy, np.random.default_rng(1))
    # shot noise: sigma grows with light (in linear units), so more grey levels when bright
    assert srgb_to_linear(bright / 255.0).std() > 2 * srgb_to_linear(dark / 255.0).std()


def test_webcam_render_keeps_returning_the_truth():
    view = next(random_views(1, seed=3, webcam=True))
    r = view.rendered
    assert r.image.dtype == np.uint8 and r.vertices_px is not None and r.marker_visible
    assert view.style.camera is not None and not view.style.camera.ideal


@pytest.mark.slow  # many renders: left out of `make test-fast`
def test_nominal_magenta_through_the_webcam():
    errors, found, total = _errors("nominal", ExtractorParams())
    assert found >= 0.98 * total, f"found {found}/{total}"
    assert np.median(errors) <= 0.12, f"median {np.median(errors):.3f} px"
    assert np.percentile(errors, 95) <= 0.4, f"p95 {np.percentile(errors, 95):.3f} px"


@pytest.mark.slow  # many renders: left out of `make test-fast`
def test_default_model_finds_process_magenta_and_nothing_in_photographs():
    errors, found, total = _errors("process", ExtractorParams(), n=40)
    assert found >= 0.97 * total, f"found {found}/{total}"
    assert np.median(errors) <= 0.15
    ex = RhombusExtractor()
    hits = []
    for i, img in enumerate(_photographs()):
        ex.reset()
        if ex.extract(img).found:
            hits.append(i)
    assert hits == []


def test_a_hot_pink_rhombus_is_not_the_marker():
    view = next(random_views(1, seed=4, webcam=True))
    cam = CameraModel.paper()
    T = marker_pose(0.35, 320, 240, cam)
    style = replace(view.style, marker_bgr=(180, 105, 255), draw_body=True)
    img = render_view(cam, T, marker_points_m=Geometry().marker_points(), style=style).image
    assert not RhombusExtractor().extract(img).found
    style = replace(style, marker_bgr=INKS_BGR["nominal"])
    img = render_view(cam, T, marker_points_m=Geometry().marker_points(), style=style).image
    assert RhombusExtractor().extract(img).found


@pytest.mark.slow
@pytest.mark.parametrize("ink", ["process", "bluish"])
def test_learn_round_trip(ink, tmp_path):
    model = _learned(ink)
    path = tmp_path / "ink.toml"
    write_colour_file(path, model, "test")
    dep = parse_deployment({"services": {"vertex_extractor": {"colour_file": "ink.toml"}}},
                           tmp_path / "deploy.toml")
    loaded = dep.settings["vertex_extractor"].colour
    assert loaded.centre == pytest.approx(model.centre, abs=1e-5)
    errors, found, total = _errors(ink, ExtractorParams(colour=loaded), n=40)
    assert found >= 0.97 * total, f"found {found}/{total}"
    assert np.median(errors) <= 0.15, f"median {np.median(errors):.3f} px"
    ex = RhombusExtractor(ExtractorParams(colour=loaded))
    assert not any(ex.extract(img).found for img in _photographs(10))


def test_a_bad_colour_file_names_the_file_and_the_field(tmp_path):
    (tmp_path / "ink.toml").write_text("[colour]\ncentre = [0.7, 0.0]\nmax_distance = -1\n")
    with pytest.raises(ConfigError, match=r"ink\.toml.*colour\.max_distance"):
        parse_deployment({"services": {"vertex_extractor": {"colour_file": "ink.toml"}}},
                         tmp_path / "deploy.toml")
    with pytest.raises(ConfigError, match=r"missing\.toml.*cannot read"):
        parse_deployment({"services": {"vertex_extractor": {"colour_file": "missing.toml"}}},
                         tmp_path / "deploy.toml")


def test_learn_refuses_an_image_without_the_marker(tmp_path):
    path = tmp_path / "room.png"
    cv2.imwrite(str(path), _photographs(1)[0])
    with pytest.raises(LearnError, match=r"room\.png: no marker found"):
        learn([("room.png", cv2.imread(str(path)))])
    out = cli_here("marker", "learn", str(path), "--out", str(tmp_path / "x.toml"))
    assert out.returncode == 2 and "no marker found" in out.stderr
    assert not (tmp_path / "x.toml").exists()


def test_paper_mode_walks_the_columns_as_table_1_says():
    from services.vertex_extractor.extractor import read_only
    from services.vertex_extractor.paper import OK, table1, table2
    img = np.full((200, 300, 3), 90, np.uint8)
    rhombus = np.array([[60, 100], [150, 40], [240, 100], [150, 160]], np.int32)
    cv2.fillConvexPoly(img, rhombus, (255, 0, 255), cv2.LINE_8)  # whole pixels, no blending
    marker = np.all(img == (255, 0, 255), axis=-1)
    colour = ColourModel()
    sx, sy, dx, min_len = 147, 95, 3, 12
    status, U, D = table1(read_only(img), sx, sy, min_len, dx, colour.lut, colour.vector)
    assert status == OK
    xs = U[:, 0]
    assert np.all(np.diff(xs) == dx) and sx in xs  # Δx apart through P_0
    assert np.array_equal(U, np.round(U)) and np.array_equal(D, np.round(D))  # whole pixels
    for (x, u), (_, d) in zip(U.astype(int), D.astype(int), strict=True):
        assert marker[u, x] and not marker[u - 1, x]  # U_k: the last marker pixel upward
        assert marker[d, x] and not marker[d + 1, x]
        assert d - u >= min_len
    # each column starts from the previous chord's midpoint moved Δx, and the walk ends where
    # that pixel is not the marker's or its chord is shorter than MIN_LEN
    for k in range(len(xs)):
        if xs[k] != sx:
            j = k - 1 if xs[k] > sx else k + 1  # the column walked before this one
            assert U[k, 1] <= int(U[j, 1] + D[j, 1]) // 2 <= D[k, 1]
    for end, step in ((len(xs) - 1, dx), (0, -dx)):
        x_next, mid = int(xs[end]) + step, int(U[end, 1] + D[end, 1]) // 2
        if marker[mid, x_next]:
            u = d = mid
            while marker[u - 1, x_next]:
                u -= 1
            while marker[d + 1, x_next]:
                d += 1
            assert d - u < min_len
    # Table 2: the greedy split finds the two sides of the top vertex of these exact points
    aL, _, aR, _, n_left = table2(U)
    assert aL < 0 < aR  # image y grows downward: the left upper side rises to the right
    assert abs(n_left - np.sum(xs <= 150)) <= 2


@pytest.mark.slow  # many renders: left out of `make test-fast`
def test_paper_mode_is_a_selectable_method_and_less_accurate_than_ours():
    ours, _, _ = _errors("nominal", ExtractorParams(), n=30)
    paper, found, total = _errors("nominal", ExtractorParams(method="paper"), n=30)
    assert found >= 0.8 * total
    assert np.median(paper) > 2 * np.median(ours)
