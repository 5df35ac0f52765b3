"""Both IPPE branches kept until the evidence of several frames separates them (no bus inside).

A planar view has two poses that fit it: IPPE's two candidates. Far away, or seen nearly
face-on with the camera at the marker's height, the second is a yaw mirror that fits almost as
well, so a single frame's choice flips with the noise, and a continuity prior would then keep
whatever the first frame chose. Instead each branch is a track: every frame, each candidate is
given to the track whose last rotation is nearer, and adds its cost to it, the reprojection
error in units of the vertex noise plus the upright prior, with a forgetting factor. The
estimator follows the cheaper track; while the two differ by less than ``decide_cost`` it says
so (``ambiguous``). A candidate far from both tracks (the marker lost and found elsewhere)
starts afresh, so unrelated frames pay nothing for the tracking. Where the two branches meet
(``crossed``), the past evidence counts for neither: the caller (``sequence``) says when.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from services.core.camera import CameraModel
from services.pose_estimator.estimate import TILT_HUBER_SIGMAS
from services.pose_estimator.p4p import prior_cost


def rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle (rad) of the rotation between two rotation matrices."""
    return math.acos(max(-1.0, min(1.0, (float(np.trace(Ra.T @ Rb)) - 1.0) / 2.0)))


@dataclass
class _Track:
    R: np.ndarray
    cost: float


@dataclass
class BranchTracker:
    """The two branches' tracks and which one the estimator follows.

    Args:
        forget: weight of the past cost per frame (0.9: about ten frames of memory).
        decide_cost: cost difference (in units of squared noise) that decides a branch.
        max_jump_rad: a candidate farther than this from both tracks restarts them.
        max_move_m: so does a marker that moved farther than this since the last frame.
        min_separation_rad: pairings of candidates to tracks closer than this in total angle
            are not told apart: that frame adds no evidence.
    """

    forget: float = 0.9
    decide_cost: float = 6.0
    max_jump_rad: float = math.radians(25.0)
    min_separation_rad: float = math.radians(8.0)
    max_move_m: float = 0.05
    tracks: list[_Track] = field(default_factory=list)
    position: np.ndarray | None = None
    skipped: bool = False  # the last frame's candidates could not be told apart


    def reset(self) -> None:
        self.tracks, self.position = [], None

    def crossed(self) -> None:
        """The two branches met (their poses within the noise): which track continues which
        branch is unknown from here, so the evidence gathered before counts for neither."""
        if self.tracks:
            low = min(t.cost for t in self.tracks)
            for t in self.tracks:
                t.cost = low

    def update(self, candidates: list[tuple[np.ndarray, float]], position: np.ndarray
               ) -> tuple[np.ndarray | None, bool]:
        """``candidates``: (rotation, cost) of each IPPE candidate this frame; ``position``:
        the marker's (well determined) position in the camera, m. Returns the rotation of the
        branch to follow (None on a fresh start: one frame has no history to add to its own
        choice) and whether the branches are still ambiguous."""
        if not candidates:
            raise ValueError("no candidates")
        moved = self.position is None or float(np.linalg.norm(position - self.position)) > \
            self.max_move_m
        self.position = np.array(position, dtype=np.float64)
        if moved or len(self.tracks) != len(candidates) or min(
                min(rotation_angle(t.R, R) for t in self.tracks) for R, _ in candidates
        ) > self.max_jump_rad:
            self.tracks = [_Track(R, cost) for R, cost in candidates]
            self.skipped = False
            return None, len(candidates) > 1
        else:
            order = self._assign([R for R, _ in candidates])
            self.skipped = order is None
            if order is not None:  # a frame whose candidates do not say which is which: skip
                for track, (R, cost) in zip(order, candidates, strict=True):
                    track.R, track.cost = R, self.forget * track.cost + cost
        best = min(self.tracks, key=lambda t: t.cost)
        if len(self.tracks) < 2:
            return best.R, False
        other = max(self.tracks, key=lambda t: t.cost)
        return best.R, other.cost - best.cost < self.decide_cost

    def _assign(self, rotations: list[np.ndarray]) -> list[_Track] | None:
        """The tracks in the order of ``rotations`` (the cheaper pairing), or None when the
        two pairings are too alike to tell (the tracks would swap identities)."""
        a, b = self.tracks
        keep = rotation_angle(a.R, rotations[0]) + rotation_angle(b.R, rotations[1])
        swap = rotation_angle(b.R, rotations[0]) + rotation_angle(a.R, rotations[1])
        if abs(keep - swap) < self.min_separation_rad:
            return None
        return [a, b] if keep <= swap else [b, a]


def candidate_cost(camera: CameraModel, T_camera_marker: np.ndarray, points: np.ndarray,
                   vertices_px: np.ndarray, sigma_px: float, up_cam: np.ndarray | None,
                   tilt_sigma_rad: float) -> float:
    """A candidate's cost in units of squared noise: its reprojection error over the vertex
    noise, plus the upright prior (the marker's normal level)."""
    R, t = T_camera_marker[:3, :3], T_camera_marker[:3, 3]
    projected = camera.project(points @ R.T + t)
    cost = float(np.sum((projected - vertices_px) ** 2)) / sigma_px ** 2
    if up_cam is not None:
        cost += prior_cost(float(R[:, 2] @ up_cam), 1.0 / tilt_sigma_rad,
                           math.sin(TILT_HUBER_SIGMAS * tilt_sigma_rad))
    return cost
