"""Value types of loop closure: the compact per-submap record, candidates, constraints, stats.

A loop between the current submap ``i`` and an earlier submap ``m`` is verified into a
:class:`LoopConstraint`: 3D point pairs ``X_i`` (in submap-i local coordinates and units) and
``X_m`` (submap-m local) that should coincide, plus the relative transform ``T_i_m`` (maps
submap-m local points to submap-i local; Sim(3) for mono, SE(3) for RGB-D) fitted to them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gsslam.errors import GsslamError


class LoopError(GsslamError):
    """Loop-closure input is malformed (wrong shapes, unknown submap id, ...)."""


@dataclass(frozen=True)
class ViewFeatures:
    """ORB features of one keyframe, lifted to the submap's local frame.

    ``keypoints``: [F, 2] pixels at point-map resolution; ``descriptors``: [F, 32] uint8;
    ``points_local``: [F, 3] the keypoints' 3D points in submap-local coordinates.
    """

    keypoints: np.ndarray
    descriptors: np.ndarray
    points_local: np.ndarray


@dataclass(frozen=True)
class SubmapRecord:
    """What the detector keeps per submap: bounded size whatever the input resolution.

    - ``K``: [3, 3] intrinsics of ``depth_small``; ``T_local_cam``: [V, 4, 4].
    - ``depth_small``: [V, hs, ws] z in local units (NaN unknown), for visibility tests.
    - ``points_local``: [N, 3] subsampled points; ``point_view``: [N] the view each came from.
    - ``center_local``: [3], ``radius``: bounding sphere of the points (local units).
    - ``appearance``: [V, D] unit-norm global descriptors; ``features``: per-view ORB.
    - ``median_depth``: median point depth in local units (scale of the submap).
    """

    submap_id: int
    frame_indices: tuple[int, ...]
    K: np.ndarray
    T_local_cam: np.ndarray
    depth_small: np.ndarray
    points_local: np.ndarray
    point_view: np.ndarray
    center_local: np.ndarray
    radius: float
    appearance: np.ndarray
    features: tuple[ViewFeatures, ...]
    median_depth: float


@dataclass(frozen=True)
class LoopCandidate:
    """An earlier submap ``m`` that overlaps the current submap ``i`` under the current estimate.

    ``point_overlap``: reprojection overlap ratio in [0, 1]; ``appearance``: appearance overlap in
    [0, 1]; ``score = 0.7 * point_overlap + 0.3 * appearance``; ``view_pairs``: (view of i, view of
    m) pairs, most co-visible first, to match during verification.
    """

    i: int
    m: int
    point_overlap: float
    appearance: float
    score: float
    view_pairs: tuple[tuple[int, int], ...]


@dataclass(frozen=True)
class LoopConstraint:
    """A verified loop: the "loop submap" (i, m) and its joint constraint set.

    ``X_i``, ``X_m``: [N, 3] RANSAC-inlier point pairs in the local frames of submaps i and m;
    ``T_i_m``: [4, 4] fitted to them (``X_i ~ T_i_m X_m``); ``inlier_ratio``: inliers / matches;
    ``score``: the candidate's combined overlap score; ``threshold``: inlier distance in
    submap-i local units (the unit of the residual checks).
    """

    i: int
    m: int
    X_i: np.ndarray
    X_m: np.ndarray
    T_i_m: np.ndarray
    inlier_ratio: float
    score: float
    threshold: float
    view_i: np.ndarray | None = None  # [N] the keyframe of submap i each point was seen in (None: unknown)
    view_m: np.ndarray | None = None  # [N] the same in submap m

    def __post_init__(self) -> None:
        if self.X_i.shape != self.X_m.shape or self.X_i.ndim != 2 or self.X_i.shape[1] != 3:
            raise LoopError(f"X_i and X_m must both be [N, 3], got {self.X_i.shape} and {self.X_m.shape}")
        if self.T_i_m.shape != (4, 4):
            raise LoopError(f"T_i_m must be [4, 4], got {self.T_i_m.shape}")

    def __len__(self) -> int:
        return len(self.X_i)


@dataclass(frozen=True)
class Verdict:
    """The outcome of verifying one candidate: the loop (``None`` when refused), the 3D matches, the
    RANSAC inliers and why: "verified", "too few matches", "too few inliers", "low inlier ratio"."""

    loop: LoopConstraint | None
    matches: int
    inliers: int
    why: str


@dataclass
class LoopStats:
    """Counters for metrics.json.

    ``candidates``: pairs passing the overlap/score test; ``detected``: candidates verified by
    RANSAC; ``accepted``: verified loops handed to the graph (passed the drift gate);
    ``rejected``: verified loops refused by the drift gate plus loops removed after optimisation;
    ``unverified``: candidates refused by verification, counted by reason (:class:`Verdict`).
    """

    candidates: int = 0
    detected: int = 0
    accepted: int = 0
    rejected: int = 0
    rejected_after_optimisation: int = 0
    detect_seconds: float = 0.0
    submaps_checked: int = 0
    log: list[dict] = field(default_factory=list)
    unverified: dict[str, int] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "candidates": self.candidates,
            "detected": self.detected,
            "accepted": self.accepted,
            "rejected": self.rejected,
            "rejected_after_optimisation": self.rejected_after_optimisation,
            "mean_detect_ms": 1e3 * self.detect_seconds / max(1, self.submaps_checked),
            "unverified": dict(self.unverified),
            "loops": list(self.log),
        }
