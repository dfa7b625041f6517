"""Monocular submap encoder: classical structure from motion on dense flow tracks.

At point-map resolution, for K+1 keyframes with frame 0 shared with the previous submap:

1. Tracks from frame 0: flows between consecutive keyframes are chained (0 -> i) and checked
   forward-backward against the chained backward flows; only textured pixels are used.
2. Two-view initialisation: essential matrix (RANSAC) + recoverPose between frame 0 and the
   farthest frame with good geometry, checked triangulation (cheirality, reprojection, parallax)
   and homography-vs-essential model selection (:func:`gsslam.frontend.two_view.two_view_pose`;
   RANSAC, or MAGSAC++ with ``encoder.mono_essential_method=magsac``).
3. One scale for the submap: with ``shared_depth`` the median ratio shared/triangulated depth
   (so the scale chains across submaps); without, median frame-0 depth = 1.
4. PnP RANSAC + LM for the other frames against the triangulated frame-0 points, then a small
   bundle adjustment of all poses and frame-0 inverse depths (its tracks: the essential inliers, or
   with ``encoder.mono_ba_tracks=all`` every sampled track triangulated with the two-view pose, so
   the BA does not inherit the RANSAC sample's rotation: docs/results.md, session 8); with
   ``encoder.mono_shared_depth_sigma > 0`` (off by default: docs/results.md, sessions 6-7) the
   shared depth is a prior on those inverse depths (relative std, divided by the shared depth's own
   confidence: its parallax in the previous submap; none where that is low), so the translations
   are tied to the previous submap's geometry track by track instead of by one median.
5. Dense depth per frame: two-ray triangulation of its flow to the frame with the widest
   baseline; confidence grows with the parallax angle (:mod:`gsslam.frontend.mono_depth`).

Low parallax / pure rotation (or no texture): no triangulation. With ``shared_depth`` the
poses come from PnP against the shared frame's depth and depths are propagated from it
(confidence 0.5); without it, rotations come from homographies, translations are zero and the
point maps are empty (confidence 0). ``meta["degenerate"]`` and ``meta["reason"]`` say which. In a
turn (``encoder.mono_turn_rotation``) a frame whose view has left the shared depth is posed against a
plane (rotation only); a window whose shared depth is a placeholder sets ``meta["shared_placeholder"]``.
"""

from __future__ import annotations

import logging

import numpy as np

from gsslam.config import EncoderConfig
from gsslam.frontend.encoder import (
    check_frames,
    pointmap_intrinsics,
    register_encoder,
    resize_depth,
    resize_image,
    robust_depth_stats,
)
from gsslam.frontend.flow import DISFlow, FlowEstimator, chained_flows
from gsslam.frontend.mono_depth import (
    FB_THRESHOLD_PX,
    PROPAGATED_CONFIDENCE,
    dense_depth,
    fill_missing_depth,
    propagate,
)
from gsslam.frontend.mono_init import (
    choose_hypothesis,
    local_poses,
    rotation_deg,
    score_tracks,
    two_view_hypotheses,
)
from gsslam.frontend.mono_link import chain_link
from gsslam.frontend.pose_estimation import pnp, random_flow_matches
from gsslam.frontend.two_view import two_view_pose
from gsslam.geometry import backproject, depth_to_points, invert_T
from gsslam.types import Frame, SubmapEncoding

log = logging.getLogger(__name__)


class MonoEncoder:
    """Sub-track encoder for colour-only input; units: the previous submap's (or median depth 1)."""

    def __init__(self, cfg: EncoderConfig, flow: FlowEstimator, seed: int = 0) -> None:
        self.cfg = cfg
        self.flow = flow
        if cfg.mono_dis_preset and isinstance(flow, DISFlow) and flow.preset != cfg.mono_dis_preset:
            # the chained tracks and the dense triangulation may use a finer DIS than tracking does
            # (measured: better on TUM teddy and KITTI 01, worse on KITTI 06; docs/results.md)
            self.flow = DISFlow(cfg.mono_dis_preset, flow.max_side, flow.finest_scale)
        self.rng = np.random.default_rng(seed)

    # -- main ---------------------------------------------------------------------------------
    def encode(
        self,
        frames: list[Frame],
        shared_depth: np.ndarray | None = None,  # [H, W] or [h, w], previous submap units
        shared_pose_hint: np.ndarray | None = None,
        shared_confidence: np.ndarray | None = None,  # [H, W] or [h, w] in [0, 1], shared_depth's
    ) -> SubmapEncoding:
        check_frames(frames, need_depth=False)
        cfg = self.cfg
        intr = pointmap_intrinsics(frames[0].intrinsics, cfg.pointmap_max_side)
        K = intr.K
        n = len(frames)
        imgs = [resize_image(f.image, intr) for f in frames]
        sd = None
        if shared_depth is not None:
            sd = resize_depth(np.asarray(shared_depth, dtype=np.float32), intr)
            with np.errstate(invalid="ignore"):
                sd[~(sd > 0)] = np.nan
        sc = None
        if sd is not None and shared_confidence is not None:
            sc = resize_depth(np.nan_to_num(np.asarray(shared_confidence, np.float32)), intr)
        fw, bw, valid = chained_flows(imgs, self.flow, FB_THRESHOLD_PX, self.cfg.min_texture_gradient)
        meta: dict = {"degenerate": False, "reason": "ok", "pnp_failed": [], "scale_source": "median_depth"}
        if sd is not None and unmeasured(sd, cfg.min_inliers):  # a low-parallax turn left a placeholder:
            meta["shared_placeholder"] = True  # the scale is a guess, and the graph's scale link says so

        # two-view initialisation against the farthest usable frame
        tv, ref = None, None
        for r in range(n - 1, 0, -1):
            uv0_tv, uvr_tv, _ = random_flow_matches(fw[r], valid[r], None, cfg.max_points_per_frame, self.rng)
            res = two_view_pose(
                K, uv0_tv, uvr_tv, cfg.ransac_threshold_px, cfg.min_inliers, cfg.min_parallax_deg
            )  # the reference frame by RANSAC, whatever the estimator (mono_init.two_view_hypotheses)
            meta.setdefault("two_view", []).append(
                {
                    "frame": r,
                    "reason": res.reason,
                    "parallax_deg": res.median_parallax_deg,
                    "essential_inliers": res.essential_inliers,
                    "homography_inliers": res.homography_inliers,
                }
            )
            if res.T_b_a is not None:
                tv, ref = res, r
                break
        if tv is None:
            return self._degenerate(frames, imgs, fw, bw, valid, sd, intr, meta)

        # the local poses: each two-view hypothesis through scale, PnP and the BA; with several,
        # the one whose BA poses explain all tracks best (gsslam/frontend/mono_init.py)
        hyps = [tv]
        if cfg.mono_two_view_hypotheses > 1 or cfg.mono_essential_method != "ransac":
            hyps = two_view_hypotheses(K, uv0_tv, uvr_tv, tv, cfg, self.rng)
        all_tracks = None
        if cfg.mono_ba_tracks == "all":
            uv_all, uv_ref, _ = random_flow_matches(
                fw[ref], valid[ref], None, cfg.max_points_per_frame, self.rng
            )
            all_tracks = (uv_all, uv_ref)
        prior = None
        if cfg.mono_shared_depth_sigma > 0:
            prior = lambda uv: self._shared_depth_prior(sd, sc, uv, intr)  # noqa: E731
        sols = [
            local_poses(K, h, ref, fw, valid, intr.width, intr.height, cfg, sd, all_tracks, prior)
            for h in hyps
        ]
        best = 0
        if len(sols) > 1:
            tracks = score_tracks(fw, valid, ref, intr.width, intr.height, cfg.max_points_per_frame, self.rng)
            best, costs = choose_hypothesis(K, sols, tracks, cfg.ransac_threshold_px)
            meta["hypotheses"] = [
                {
                    "rotation_deg": rotation_deg(h.T_b_a, hyps[0].T_b_a),
                    "essential_inliers": h.essential_inliers,
                    "cost": c,
                }
                for h, c in zip(hyps, costs)
            ]
            meta["hypothesis"] = best
        tv, sol = hyps[best], sols[best]
        for i in sol.info["pnp_failed"]:
            log.warning(
                "mono encoder: PnP failed for keyframe %d (%d inliers); copying the previous pose",
                frames[i].index,
                sol.info["pnp_inliers"][i],
            )
        meta.update({k: v for k, v in sol.info.items() if k != "pnp_inliers"})
        meta["T_i_0_pnp"] = sol.T_i_0_pnp  # [n, 4, 4] before the BA (tests/accuracy/mono_rotation_probe.py)
        T_i_0, rho, s = sol.T_i_0.copy(), sol.rho, sol.scale
        meta["T_i_0_ba"] = T_i_0.copy()
        if "shared_depth_prior" not in sol.info:
            g = float(sol.median_depth_before / np.median(1.0 / rho))  # hold the scale chosen above
        else:
            g = 1.0  # the shared depth held it, track by track
        T_i_0[:, :3, 3] *= g
        T_local = np.stack([invert_T(T) for T in T_i_0])
        if meta.get("shared_placeholder"):
            meta["scale_source"] = "placeholder"

        points, conf = dense_depth(self.flow, imgs, fw, bw, valid, T_local, intr, cfg)
        if sd is not None and not _is_constant(sd):
            # the dense frame-0 depth against the shared depth: one robust log-ratio (on every pixel
            # both have, or weighted by confidence) puts the whole submap in the previous one's units
            link = chain_link(sd, points[0, ..., 2], sc, conf[0], cfg)  # gsslam/frontend/mono_link.py
            if link is not None and 0 < cfg.mono_link_max_spread < link.spread:
                # a right two-view geometry triangulates frame 0 as the shared depth up to one factor;
                # a wrong one bends it (docs/results.md, "Two-view windows that break a mono chain,
                # session 15"): refused, the window carries the shared depth as a low-parallax one does
                log.info(
                    "mono encoder: keyframes %s: two-view depth disagrees with the shared depth "
                    "(log-ratio spread %.3f); carrying the shared depth",
                    [f.index for f in frames],
                    link.spread,
                )
                refused = {"frame": ref, "link_spread": link.spread, "parallax_deg": tv.median_parallax_deg}
                meta = {k: meta[k] for k in ("two_view", "shared_placeholder") if k in meta}
                meta.update(degenerate=False, reason="ok", pnp_failed=[], scale_source="median_depth")
                meta["two_view_refused"] = refused
                return self._degenerate(frames, imgs, fw, bw, valid, sd, intr, meta)
            if link is not None:
                g2, meta["link_sigma"] = float(np.exp(link.log_scale)), link.sigma
                points *= g2
                T_local[:, :3, 3] *= g2
                g *= g2
                meta["scale_source"] = "shared_depth"
                meta["dense_scale_correction"] = g2
            else:  # the window's depth shares too few pixels with the shared depth (a sliver a turn left)
                meta["unlinked"] = True
        if sd is not None:
            # Frame 0 speaks the shared depth, on exactly its pixels: the graph compares the two depth
            # maps of the shared frame by their medians, and on a scene with near and far parts
            # (a bimodal depth) medians over different pixel sets differ by factors of 2-4.
            # (A placeholder plane is no geometry: it only fills the holes of the triangulation.)
            has = np.isfinite(sd)
            if _is_constant(sd):
                fill = has & ~np.isfinite(points[0, ..., 2])
                points[0][fill] = depth_to_points(K, sd)[fill]
                conf[0][fill] = 0.0
            else:
                conf[0] = np.where(has, np.maximum(conf[0], PROPAGATED_CONFIDENCE), 0.0)
                points[0] = depth_to_points(K, sd)
        fill_missing_depth(points, conf, bw, T_local, K, self.cfg.min_inliers, meta)
        meta.update(
            reference_frame=ref,
            scale=s * g,
            parallax_deg=tv.median_parallax_deg,
            depth_stats=[robust_depth_stats(p[..., 2]) for p in points],
            support_points=len(sol.uv0),
        )
        return SubmapEncoding([f.index for f in frames], T_local, points, conf, intr, meta)

    def _shared_depth_prior(self, sd, sc, uv0, intr):  # -> ([N] or None, [N] or float)
        """The BA prior from the shared depth: inverse depth at the frame-0 track pixels (NaN where none)
        and its relative std. With the shared depth's confidence ``sc`` (the previous submap's
        triangulation parallax / (4 min_parallax), :func:`gsslam.frontend.mono_depth.dense_depth`) the
        std is per track, ``sigma / confidence`` (a rotation error d at parallax p shifts a triangulated
        depth by ~d/p), and pixels below ``mono_shared_depth_min_confidence`` get none: far points seen at
        low parallax no longer pull the scale. None without enough of it (or for a placeholder plane, no
        geometry)."""
        cfg = self.cfg
        if sd is None or _is_constant(sd):
            return None, 0.0
        ui = np.clip(np.round(uv0).astype(int), 0, [intr.width - 1, intr.height - 1])
        z = sd[ui[:, 1], ui[:, 0]].astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            rho = np.where(np.isfinite(z) & (z > 0), 1.0 / z, np.nan)
        sigma: float | np.ndarray = cfg.mono_shared_depth_sigma
        if sc is not None and cfg.mono_shared_depth_by_confidence:
            c = sc[ui[:, 1], ui[:, 0]]
            sigma = shared_depth_sigmas(c, cfg.mono_shared_depth_sigma, cfg.mono_shared_depth_min_confidence)
            rho[~np.isfinite(sigma)] = np.nan
        return (rho, sigma) if np.isfinite(rho).sum() >= cfg.min_inliers else (None, 0.0)

    # -- low parallax / rotation / no texture -------------------------------------------------
    def _degenerate(self, frames, imgs, fw, bw, valid, sd, intr, meta) -> SubmapEncoding:
        """No two-view geometry. Poses by PnP against the shared depth (or, without one, against a
        unit-depth plane: the chain's unit convention "median depth 1"); with zero parallax the depth
        is unobservable and the plane's depth is a placeholder with confidence 0 (``meta
        ["placeholder_depth"]``) that keeps the scale of the chain and the next submap's shared frame."""
        n, (h, w), K = len(frames), imgs[0].shape[:2], intr.K
        meta["degenerate"] = True
        T_local = np.tile(np.eye(4), (n, 1, 1))
        points = np.full((n, h, w, 3), np.nan, np.float32)
        conf = np.zeros((n, h, w), np.float32)
        n_valid = [int(v.sum()) for v in valid[1:]]
        if max(n_valid, default=0) < self.cfg.min_inliers:
            meta["reason"] = "no_texture"
            log.warning(
                "mono encoder: keyframes %s have no trackable texture; identity poses, empty point maps",
                [f.index for f in frames],
            )
            return SubmapEncoding([f.index for f in frames], T_local, points, conf, intr, meta)
        placeholder = sd is None or unmeasured(sd, self.cfg.min_inliers)
        if placeholder:
            meta["reason"] = "low_parallax_unit_depth"
            meta["placeholder_depth"] = True
            z = 1.0 if sd is None or not np.isfinite(sd).any() else float(np.nanmedian(sd))
            sd = np.full((h, w), z, np.float32)
            c0 = 0.0
        else:
            meta["reason"] = "low_parallax_shared_depth"
            meta["scale_source"] = "shared_depth"
            c0 = PROPAGATED_CONFIDENCE
        P0 = depth_to_points(K, sd)
        points[0], conf[0] = P0, np.where(np.isfinite(sd), c0, 0.0)
        thr = 2.0 * self.cfg.ransac_threshold_px
        plane = np.full((h, w), float(np.nanmedian(sd)), np.float32)
        for i in range(1, n):
            uv0, uvi, z = random_flow_matches(fw[i], valid[i], sd, self.cfg.max_points_per_frame, self.rng)
            res = pnp(backproject(K, uv0, z), uvi, K, thr, self.cfg.min_inliers)
            if res.T_tgt_src is None and self.cfg.mono_turn_rotation and not placeholder:
                # the turn has left the carried depth behind: every flow match against a plane at its
                # median depth, a rotation-only model (at zero parallax the depth does not enter)
                m = self.cfg.max_points_per_frame
                uv0, uvi, z = random_flow_matches(fw[i], valid[i], plane, m, self.rng)
                res = pnp(backproject(K, uv0, z), uvi, K, thr, self.cfg.min_inliers)
                if res.T_tgt_src is not None:
                    meta.setdefault("pnp_rotation_only", []).append(i)
            if res.T_tgt_src is None:
                meta["pnp_failed"].append(i)
                T_local[i] = T_local[i - 1]
            else:
                T_local[i] = invert_T(res.T_tgt_src)
        for i in range(1, n):  # a placeholder stays a constant plane, so the next submap knows it as one
            points[i] = P0 if placeholder else propagate(P0, bw[i], invert_T(T_local[i]))
            conf[i] = np.where(np.isfinite(points[i, ..., 2]), c0, 0.0)
        fill_missing_depth(points, conf, bw, T_local, K, self.cfg.min_inliers, meta)
        log.warning(
            "mono encoder: no reliable two-view geometry in keyframes %s (%s)",
            [f.index for f in frames],
            meta["reason"],
        )
        meta["depth_stats"] = [robust_depth_stats(p[..., 2]) for p in points]
        return SubmapEncoding([f.index for f in frames], T_local, points, conf, intr, meta)


def shared_depth_sigmas(
    confidence: np.ndarray,  # [N] the shared depth's confidence at the tracks, in [0, 1]
    sigma: float,  # relative std at confidence 1
    min_confidence: float,
) -> np.ndarray:  # [N] relative std of the depth prior per track; inf: no prior
    """``sigma / confidence``, none (inf) below ``min_confidence`` (and at confidence 0).

    The mono confidence is parallax / (4 min_parallax), so this std grows as 1 / parallax: the
    relative depth error that a fixed angular error gives at that parallax.
    """
    c = np.nan_to_num(np.asarray(confidence, np.float64), nan=0.0)
    ok = (c >= min_confidence) & (c > 0)
    return np.where(ok, sigma / np.where(ok, c, 1.0), np.inf)


def _is_constant(depth: np.ndarray) -> bool:  # [h, w]
    """A depth map without structure (a placeholder plane handed back as shared depth)."""
    z = depth[np.isfinite(depth)]
    return len(z) > 0 and float(z.max() - z.min()) <= 1e-6 * float(abs(z).max())


def unmeasured(depth: np.ndarray, min_inliers: int) -> bool:  # [h, w]
    """A shared depth that measures nothing: too few pixels, or a placeholder plane."""
    return int(np.isfinite(depth).sum()) < min_inliers or _is_constant(depth)


register_encoder("mono", lambda cfg, flow: MonoEncoder(cfg, flow))
