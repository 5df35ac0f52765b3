"""Simulated photographs of a planar target with known intrinsics, distortion and pose."""

from __future__ import annotations

import cv2
import numpy as np

from services.core.camera import CameraModel


def pixel_rays(camera: CameraModel, step: int = 4, supersample: int = 1) -> np.ndarray:
    """Ideal normalised coordinates (H', W', 2) of every (sub)pixel of the camera's image,
    removing distortion; computed on a coarse grid and interpolated (smooth map)."""
    W, H = camera.width * supersample, camera.height * supersample
    xs = np.arange(0, W + step, step)
    ys = np.arange(0, H + step, step)
    gx, gy = np.meshgrid(xs, ys)
    px = np.column_stack([(gx.ravel() + 0.5) / supersample - 0.5,
                          (gy.ravel() + 0.5) / supersample - 0.5])
    from services.core.camera import undistort_px
    coarse = undistort_px(camera, px).reshape(len(ys), len(xs), 2).astype(np.float32)
    full = cv2.resize(coarse, (len(xs) * step, len(ys) * step), interpolation=cv2.INTER_LINEAR)
    # resize maps sample centres: its pixel j holds coarse position j / step - (step - 1) /
    # (2 step); shift by (step - 1) / 2 so that pixel j holds coarse position j / step
    # (warpAffine's M maps source to destination: dst(x) = src(x + shift))
    shift = (step - 1) / 2
    M = np.array([[1, 0, -shift], [0, 1, -shift]], np.float32)
    full = cv2.warpAffine(full, M, (full.shape[1], full.shape[0]), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)
    return full[:H, :W]


def render_plane(camera: CameraModel, T_camera_board: np.ndarray, texture: np.ndarray,
                 texture_px_per_m: float, texture_origin_px: tuple[float, float],
                 *, supersample: int = 3, noise_sigma: float = 1.5, seed: int = 0,
                 background: int = 90, blur_sigma: float = 0.0) -> np.ndarray:
    """Greyscale photo of a planar texture. The board frame has x right, y down the texture,
    z into it; board point (x, y) m lies at texture coordinate origin + (x, y) *
    texture_px_per_m, measured from the texture's top-left *corner* (not a pixel centre)."""
    rays = pixel_rays(camera, supersample=supersample)
    R, t = T_camera_board[:3, :3], T_camera_board[:3, 3]
    n = R[:, 2]
    ray3 = np.dstack([rays, np.ones(rays.shape[:2], np.float32)])
    denom = ray3 @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        s = float(n @ t) / denom
    X = ray3 * s[..., None] - t
    board = X @ R  # R^T (X - t), row vectors
    map_x = (board[..., 0] * texture_px_per_m + texture_origin_px[0] - 0.5).astype(np.float32)
    map_y = (board[..., 1] * texture_px_per_m + texture_origin_px[1] - 0.5).astype(np.float32)
    behind = ~(s > 0)
    map_x[behind] = -1e6
    img = cv2.remap(texture.astype(np.float32), map_x, map_y, cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=background)
    img = cv2.resize(img, (camera.width, camera.height), interpolation=cv2.INTER_AREA)
    if blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma)
    rng = np.random.default_rng(seed)
    img += rng.normal(0, noise_sigma, img.shape).astype(np.float32)
    return np.clip(img + 0.5, 0, 255).astype(np.uint8)


def board_pose(distance_m: float, tilt_x_rad: float, tilt_y_rad: float, roll_rad: float,
               centre_m: tuple[float, float], offset_px: tuple[float, float],
               camera: CameraModel) -> np.ndarray:
    """T_camera_board for a board whose point ``centre_m`` is seen at image offset
    ``offset_px`` from the principal point, ``distance_m`` away, tilted and rolled."""
    from services.core.geometry import make_T, rot_x, rot_y, rot_z
    R = rot_z(roll_rad) @ rot_x(tilt_x_rad) @ rot_y(tilt_y_rad)
    ray = np.linalg.solve(camera.K, [camera.K[0, 2] + offset_px[0],
                                     camera.K[1, 2] + offset_px[1], 1.0])
    ray /= np.linalg.norm(ray)
    centre_cam = distance_m * ray
    t = centre_cam - R @ np.array([centre_m[0], centre_m[1], 0.0])
    return make_T(R, t)
