"""Local poses of a mono submap from its two-view geometry: scale, PnP, the local BA, and a choice
between several two-view hypotheses by the BA's outcome over all tracks.

OpenCV's RANSAC for the essential matrix draws its minimal samples from a fixed seed by index, so the
order of the matches is its random sample: the same matches in another order give another rotation
(0.35-2.5 deg apart on a synthetic pair, docs/results.md, "Mono local rotations, session 8"), and the
essential matrix's inliers are the tracks that agree with that rotation, so a BA over them keeps it.
:func:`two_view_hypotheses` makes ``encoder.mono_two_view_hypotheses`` of them on the reference frame
(deterministic orders from the encoder's generator), :func:`local_poses` carries each through PnP and
the BA, and :func:`track_cost` scores each BA's poses over one common set of tracks (every sampled
track of the reference frame, in every frame where it is valid), each at its best depth, with a Cauchy
kernel: a rotation error shows as residual on all tracks, not only on the ones a sample kept.

Poses are ``T_i_0`` (frame-0 points into frame i); pixels are at the encoder's point-map resolution.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from gsslam.config import EncoderConfig
from gsslam.frontend.pose_estimation import pnp, random_flow_matches
from gsslam.frontend.two_view import TwoViewResult, bundle_adjust, rays, triangulate_rays, two_view_pose
from gsslam.geometry import so3_log

log = logging.getLogger(__name__)

MIN_DISTINCT_DEG = 0.02  # a hypothesis whose rotation is this close to one already kept adds nothing


@dataclass
class LocalSolution:
    """One hypothesis carried through scale, PnP and the BA (translations at the BA's scale)."""

    T_i_0: np.ndarray  # [n, 4, 4] after the BA
    T_i_0_pnp: np.ndarray  # [n, 4, 4] before it
    rho: np.ndarray  # [N] frame-0 inverse depths of the BA's tracks, after it
    uv0: np.ndarray  # [N, 2] those tracks' pixels in frame 0
    median_depth_before: float  # median frame-0 depth of the BA's tracks before it (the scale to hold)
    scale: float  # the two-view scale s
    info: dict = field(default_factory=dict)  # meta entries: scale_source, pnp_failed, ba_tracks, ...


def two_view_hypotheses(
    K: np.ndarray,
    uv0: np.ndarray,  # [N, 2] the matches of the reference frame's two-view pose
    uvr: np.ndarray,  # [N, 2]
    first: TwoViewResult,  # the reference frame's own two-view pose (RANSAC): hypothesis 0
    cfg: EncoderConfig,
    rng: np.random.Generator,
) -> list[TwoViewResult]:
    """``first`` (or, with ``mono_essential_method=magsac``, MAGSAC++ on the same matches), then the
    estimator on up to ``mono_two_view_hypotheses - 1`` other orders of the matches; rejected ones and
    rotations within MIN_DISTINCT_DEG of one kept are left out. The reference frame is chosen before,
    by RANSAC, whatever the estimator (MAGSAC alone chose frames of much lower parallax)."""
    args = (K, uv0, uvr, cfg.ransac_threshold_px, cfg.min_inliers, cfg.min_parallax_deg)
    out = [first]
    if cfg.mono_essential_method != "ransac":
        alt = two_view_pose(*args, method=cfg.mono_essential_method)
        if alt.T_b_a is not None:
            out = [alt]
    for _ in range(cfg.mono_two_view_hypotheses - 1):
        p = rng.permutation(len(uv0))
        res = two_view_pose(K, uv0[p], uvr[p], *args[3:], method=cfg.mono_essential_method)
        if res.T_b_a is None:
            continue
        if min(rotation_deg(res.T_b_a, h.T_b_a) for h in out) < MIN_DISTINCT_DEG:
            continue
        out.append(res)
    return out


def rotation_deg(T_a: np.ndarray, T_b: np.ndarray) -> float:  # [4, 4] x2: angle between the rotations
    return float(np.degrees(np.linalg.norm(so3_log(T_a[:3, :3] @ T_b[:3, :3].T))))


def track_observations(
    uv0: np.ndarray,  # [N, 2] frame-0 pixels
    fw: list,  # [n] chained flows 0 -> i ([h, w, 2], index 0 unused)
    valid: list,  # [n] their masks ([h, w] bool)
    width: int,
    height: int,
) -> np.ndarray:  # [n, N, 2] the tracks' pixels in every frame, NaN where not valid (row 0: NaN)
    n = len(fw)
    obs = np.full((n, len(uv0), 2), np.nan)
    ui = np.clip(np.round(uv0).astype(int), 0, [width - 1, height - 1])
    lin = ui[:, 1] * width + ui[:, 0]
    for i in range(1, n):
        ok = valid[i].reshape(-1)[lin]
        obs[i, ok] = uv0[ok] + fw[i].reshape(-1, 2)[lin[ok]]
    return obs


def local_poses(
    K: np.ndarray,
    tv: TwoViewResult,
    ref: int,
    fw: list,
    valid: list,
    width: int,
    height: int,
    cfg: EncoderConfig,
    sd: np.ndarray | None,  # [h, w] shared depth (NaN where none) or None
    all_tracks: tuple[np.ndarray, np.ndarray] | None,  # (uv0, uv_ref) [M, 2] x2 for mono_ba_tracks=all
    depth_prior: Callable | None = None,  # uv0 [N, 2] -> (rho_prior [N] or None, sigma): the shared depth's
) -> LocalSolution:
    """One scale for the submap (the shared depth's median ratio, or median depth 1), PnP for the other
    frames against the triangulated tracks, then the BA (its tracks: the two-view inliers, or with
    ``all_tracks`` those tracks triangulated with this pose)."""
    n = len(fw)
    info: dict = {"scale_source": "median_depth", "pnp_failed": []}
    X0, uv0 = tv.X_a, tv.uv_a
    s = 1.0 / float(np.median(X0[:, 2]))
    if sd is not None:
        ui = np.clip(np.round(uv0).astype(int), 0, [width - 1, height - 1])
        zs = sd[ui[:, 1], ui[:, 0]]
        ok = np.isfinite(zs)
        if ok.sum() >= cfg.min_inliers:
            s = float(np.median(zs[ok] / X0[ok, 2]))
            info["scale_source"] = "shared_depth"
    X0 = X0 * s
    T_i_0 = np.tile(np.eye(4), (n, 1, 1))
    T_i_0[ref] = tv.T_b_a
    T_i_0[ref, :3, 3] *= s

    # PnP for the other frames: frame-0 track points into frame i via the chained flow
    obs = track_observations(uv0, fw, valid, width, height)
    for i in range(1, n):
        if i == ref:
            continue
        ok = np.isfinite(obs[i]).all(1)
        res = pnp(X0[ok], obs[i, ok], K, 2.0 * cfg.ransac_threshold_px, cfg.min_inliers)
        if res.T_tgt_src is None:
            info["pnp_failed"].append(i)
            T_i_0[i] = T_i_0[i - 1]
            info.setdefault("pnp_inliers", {})[i] = res.inliers
        else:
            T_i_0[i] = res.T_tgt_src

    if all_tracks is not None:
        # the BA's tracks: every sampled frame-0 track seen in the reference frame, triangulated
        # with the two-view pose, not only the essential matrix's inliers (that selection follows
        # the RANSAC sample: one rotation error kept the tracks that agree with it; docs/frontend.md)
        X_all, _, _ = triangulate_rays(K, all_tracks[0], all_tracks[1], T_i_0[ref])
        keep = np.isfinite(X_all).all(1) & (X_all[:, 2] > 0)
        if keep.sum() >= cfg.min_inliers:
            uv0, X0 = all_tracks[0][keep], X_all[keep]
            info["ba_tracks"] = int(keep.sum())
            obs = track_observations(uv0, fw, valid, width, height)
    T_pnp = T_i_0.copy()
    med_before = float(np.median(X0[:, 2]))
    rho_prior, sigma = (None, 0.0) if depth_prior is None else depth_prior(uv0)
    T_i_0, rho = bundle_adjust(
        K, T_i_0, uv0, 1.0 / X0[:, 2], obs, cfg.ransac_threshold_px,
        rho_prior=rho_prior, prior_sigma_rel=sigma,
    )  # fmt: skip
    if rho_prior is not None:
        info["shared_depth_prior"] = int(np.isfinite(rho_prior).sum())
    return LocalSolution(T_i_0, T_pnp, rho, uv0, med_before, s, info)


def track_cost(
    K: np.ndarray,
    T_i_0: np.ndarray,  # [n, 4, 4] poses (row 0: identity)
    uv0: np.ndarray,  # [N, 2] track pixels in frame 0
    obs: np.ndarray,  # [n, N, 2] their pixels in each frame (NaN where not seen)
    kernel_px: float,
    iterations: int = 8,
) -> float:
    """Cauchy cost ``sum c^2/2 log(1 + (r/c)^2)`` of all tracks' reprojection residuals at these poses,
    each track at its best inverse depth (Gauss-Newton with Cauchy weights, the poses held): the BA's
    cost over a set of tracks every hypothesis shares. Scale-free (the depths absorb the scale)."""
    seen = np.isfinite(obs).all(-1)
    seen[0] = False
    fi, pj = np.nonzero(seen)
    N = len(uv0)
    if len(fi) == 0:
        return 0.0
    b = rays(K, uv0)  # [N, 3]
    A = np.einsum("mij,mj->mi", T_i_0[fi, :3, :3], b[pj])  # [M, 3] R b: the point at rho -> 0 (infinity)
    t = T_i_0[fi, :3, 3]  # [M, 3]; the point in camera i is (A + rho t) / rho
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    target = obs[fi, pj]
    c2 = kernel_px**2

    def residuals(rho):  # -> r [M, 2], dr/drho [M, 2]
        q = A + rho[pj, None] * t
        z = np.where(q[:, 2] > 1e-9, q[:, 2], 1e-9)
        r = np.stack([fx * q[:, 0] / z + cx, fy * q[:, 1] / z + cy], 1) - target
        J = (
            np.stack([fx * (t[:, 0] * z - q[:, 0] * t[:, 2]), fy * (t[:, 1] * z - q[:, 1] * t[:, 2])], 1)
            / z[:, None] ** 2
        )
        r[q[:, 2] <= 1e-9] = 1e3  # behind the camera: a large residual
        return r, J

    # start: the widest-baseline frame's midpoint triangulation where it has one, else the median
    far = int(np.argmax(np.linalg.norm(T_i_0[:, :3, 3], axis=1)))
    rho = np.full(N, np.nan)
    if far > 0:
        ok = seen[far]
        X, _, _ = triangulate_rays(K, uv0[ok], obs[far, ok], T_i_0[far])
        rho[np.flatnonzero(ok)] = 1.0 / X[:, 2]
    good = np.isfinite(rho) & (rho > 0)
    rho[~good] = float(np.median(rho[good])) if good.any() else 1.0
    for _ in range(iterations):
        r, J = residuals(rho)
        w = 1.0 / (1.0 + np.sum(r * r, 1) / c2)  # Cauchy IRLS weights
        H = np.bincount(pj, w * np.sum(J * J, 1), minlength=N) + 1e-12
        g = np.bincount(pj, w * np.sum(J * r, 1), minlength=N)
        rho = np.maximum(rho - g / H, 0.0)
    r, _ = residuals(rho)
    return float(np.sum(0.5 * c2 * np.log1p(np.sum(r * r, 1) / c2)))


def choose_hypothesis(
    K: np.ndarray,
    solutions: list[LocalSolution],
    score_tracks: tuple[np.ndarray, np.ndarray],  # (uv0 [M, 2], obs [n, M, 2]) shared by all hypotheses
    kernel_px: float,
) -> tuple[int, list[float]]:  # (index of the lowest cost, the costs)
    costs = [track_cost(K, sol.T_i_0, score_tracks[0], score_tracks[1], kernel_px) for sol in solutions]
    return int(np.argmin(costs)), costs


def score_tracks(
    fw: list, valid: list, ref: int, width: int, height: int, max_points: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:  # (uv0 [M, 2], obs [n, M, 2])
    """The common tracks of :func:`track_cost`: up to ``max_points`` random frame-0 tracks valid in the
    reference frame, with their pixels in every frame."""
    uv0, _, _ = random_flow_matches(fw[ref], valid[ref], None, max_points, rng)
    return uv0, track_observations(uv0, fw, valid, width, height)
