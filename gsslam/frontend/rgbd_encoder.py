"""RGB-D submap encoder: sensor depth as point maps, local poses from flow + depth.

For each new keyframe i (at point-map resolution):

1. frame-to-frame: dense flow i-1 -> i (forward-backward checked) gives 3D(i-1)-2D(i) matches;
   PnP RANSAC + LM gives ``T_i_{i-1}``; chaining gives ``T_0_i``;
2. with ``encoder.rgbd_odometry=true`` (off by default; needs the optional extra
   ``pip install 'gsslam[open3d]'``): the PnP pose is refined by open3d's
   hybrid RGB-D odometry (photometric + depth), and frame i is also registered directly against
   frame 0 starting from the chained pose; the direct pose replaces the chained one when both
   agree (else ``meta["direct_rejected"]``). On TUM fr3/teddy this made the local poses *worse*
   (0.73 -> 1.22 cm, 0.43 -> 0.96 deg mean over 200 frames at 320x240), hence off.

Point maps are the (nearest-neighbour downscaled) sensor depth, holes in frame 0 filled from
``shared_depth``; confidence is 1 on valid depth, 0.3 next to depth discontinuities, 0 elsewhere.
"""

from __future__ import annotations

import logging

import numpy as np

from gsslam.config import EncoderConfig
from gsslam.frontend.encoder import (
    EncoderError,
    check_frames,
    depth_edge_mask,
    pointmap_intrinsics,
    register_encoder,
    resize_depth,
    resize_image,
    robust_depth_stats,
)
from gsslam.frontend.flow import FlowEstimator, forward_backward_mask, resize_flow, textured_mask
from gsslam.frontend.icp import icp_point_to_plane
from gsslam.frontend.joint_pose import joint_pose
from gsslam.frontend.pose_estimation import pnp, pose_distance, random_flow_matches
from gsslam.geometry import backproject, depth_to_points, invert_T, so3_log
from gsslam.types import CameraIntrinsics, Frame, SubmapEncoding

log = logging.getLogger(__name__)

FB_THRESHOLD_PX = 1.0  # at point-map resolution
EDGE_CONFIDENCE = 0.3
ICP_STRIDES = (4, 2)  # at point-map resolution (TUM 320x240: 80x60 then 160x120 points)


def _open3d():
    """The open3d module, imported on demand: it is an optional extra, used only by the odometry."""
    try:
        import open3d
    except (ImportError, OSError) as e:  # OSError: its wheel's system libraries (libusb-1.0) missing
        raise EncoderError(
            f"encoder.rgbd_odometry=true needs open3d, an optional extra ({e}): "
            "pip install 'gsslam[open3d]' (on Debian/Ubuntu its wheel also needs "
            "apt-get install libusb-1.0-0), or set encoder.rgbd_odometry=false"
        ) from e
    return open3d


def _rgbd_image(img: np.ndarray, depth: np.ndarray):  # [h, w, 3], [h, w] -> open3d RGBDImage
    o3d = _open3d()

    gray = np.ascontiguousarray(img @ np.array([0.299, 0.587, 0.114], dtype=np.float32), dtype=np.float32)
    d = np.ascontiguousarray(np.nan_to_num(depth, nan=0.0), dtype=np.float32)
    return o3d.geometry.RGBDImage.create_from_color_and_depth(
        o3d.geometry.Image(gray),
        o3d.geometry.Image(d),
        depth_scale=1.0,
        depth_trunc=1e6,
        convert_rgb_to_intensity=False,
    )


def rgbd_odometry(
    src: tuple[np.ndarray, np.ndarray],  # (image [h, w, 3], depth [h, w]) of the source frame
    tgt: tuple[np.ndarray, np.ndarray],  # same for the target frame
    intr: CameraIntrinsics,
    init: np.ndarray,  # [4, 4] T_tgt_src guess
    cfg: EncoderConfig,
) -> tuple[bool, np.ndarray]:
    """open3d hybrid RGB-D odometry: ``(success, T_tgt_src)`` (open3d returns source -> target)."""
    o3d = _open3d()
    pinhole = o3d.camera.PinholeCameraIntrinsic(intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy)
    option = o3d.pipelines.odometry.OdometryOption(
        iteration_number_per_pyramid_level=o3d.utility.IntVector([20, 10, 5]),
        depth_diff_max=cfg.odometry_depth_diff_max,
        depth_min=cfg.min_depth,
        depth_max=cfg.max_depth,
    )
    ok, T, _info = o3d.pipelines.odometry.compute_rgbd_odometry(
        _rgbd_image(*src),
        _rgbd_image(*tgt),
        pinhole,
        init,
        o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm(),
        option,
    )
    return bool(ok), np.asarray(T, dtype=np.float64)


class ColourDepthCheck:
    """Do colour (PnP on flow, colour intrinsics) and depth (ICP) agree on how far the camera turns?

    With the colour camera's focal length wrong by a factor ``k`` (unregistered Kinect v1 depth with the
    depth camera's 585 px used for colour too: 7-Scenes) PnP rotations come out ``1/k`` of the ICP
    ones; on registered, calibrated data the ratio is 1.02-1.05 (TUM teddy: point-to-plane ICP turns
    slightly short), with colour intrinsics 11 % too long 0.90-0.95 (docs/results.md). ``ratio`` is the
    least-squares factor between PnP and ICP rotation vectors over every pair so far (pairs turning
    less than 0.5 deg are skipped); ``mismatch`` once ``min_pairs`` pairs put it outside
    ``[min_ratio, max_ratio]``, and it stays set (no flip-flopping between the two pose sources).
    """

    def __init__(self, min_ratio: float, max_ratio: float, min_pairs: int = 8) -> None:
        self.min_ratio, self.max_ratio = min_ratio, max_ratio
        self.min_pairs = min_pairs
        self.pairs = 0
        self._ab = 0.0
        self._bb = 0.0
        self._latched = False
        self.latched_at = 0  # the pair count at which the mismatch latched (0: not latched)

    def add(self, T_pnp: np.ndarray, T_icp: np.ndarray) -> None:  # [4, 4] each, the same motion
        a, b = so3_log(T_pnp[:3, :3]), so3_log(T_icp[:3, :3])
        if np.degrees(np.linalg.norm(b)) < 0.5:
            return
        self.pairs += 1
        self._ab += float(a @ b)
        self._bb += float(b @ b)
        r = self.ratio
        if self.pairs >= self.min_pairs and not self.min_ratio <= r <= self.max_ratio and not self._latched:
            self._latched = True
            self.latched_at = self.pairs
            log.info(
                "colour/depth check: PnP / ICP rotation ratio %.3f after %d pairs: latched", r, self.pairs
            )

    @property
    def ratio(self) -> float:
        return self._ab / self._bb if self._bb > 0 else float("nan")

    @property
    def mismatch(self) -> bool:
        return self._latched


class RGBDEncoder:
    """Sub-track encoder for RGB-D input (metric units: metres)."""

    def __init__(self, cfg: EncoderConfig, flow: FlowEstimator, seed: int = 0) -> None:
        if cfg.rgbd_odometry:
            _open3d()  # fail at start-up, not at the second keyframe, when the extra is missing
        self.cfg = cfg
        self.flow = flow
        self.rng = np.random.default_rng(seed)
        self.check = ColourDepthCheck(cfg.rgbd_icp_auto_min_ratio, cfg.rgbd_icp_auto_max_ratio)

    @property
    def use_icp(self) -> bool:
        """ICP poses instead of PnP-on-colour-flow poses (forced, or colour found inconsistent with depth)."""
        return self.cfg.rgbd_icp or (self.cfg.rgbd_icp_auto and self.check.mismatch)

    def _depth(self, depth: np.ndarray, intr: CameraIntrinsics) -> np.ndarray:  # [H, W] -> [h, w]
        d = resize_depth(depth, intr)
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(d) | (d < self.cfg.min_depth) | (d > self.cfg.max_depth)
        d[bad] = np.nan
        return d

    def _pair_flow(self, frames: list[Frame], a: int, b: int, intr: CameraIntrinsics) -> np.ndarray:
        """Flow frame a -> frame b at point-map resolution [h, w, 2].

        Asked on the full-resolution images (the same arrays the tracker used), so that the flow
        estimator's cache returns the tracking flow last keyframe -> new keyframe without a new
        computation; the flow estimator downsizes internally to about point-map resolution anyway.
        """
        flow = self.flow(frames[a].image, frames[b].image)
        return resize_flow(flow, intr.width, intr.height)

    def _frame_to_frame(self, frames, imgs, depths, i, intr, meta) -> np.ndarray:  # -> T_i_{i-1} [4, 4]
        fw = self._pair_flow(frames, i - 1, i, intr)
        bw = self._pair_flow(frames, i, i - 1, intr)
        valid = forward_backward_mask(fw, bw, FB_THRESHOLD_PX) & textured_mask(
            imgs[i - 1]
        )  # flow is blind elsewhere
        uv_s, uv_t, z = random_flow_matches(fw, valid, depths[i - 1], self.cfg.max_points_per_frame, self.rng)
        X = backproject(intr.K, uv_s, z)  # [N, 3] in frame i-1
        res = pnp(X, uv_t, intr.K, self.cfg.ransac_threshold_px, self.cfg.min_inliers)
        meta["pnp_inliers"].append(res.inliers)
        T = res.T_tgt_src
        if T is None:
            log.warning(
                "rgbd encoder: PnP failed for frame %d -> %d (%d inliers); starting odometry from identity",
                i - 1,
                i,
                res.inliers,
            )
            meta["pnp_failed"].append(i)
            T = np.eye(4)
        if self.cfg.rgbd_icp or self.cfg.rgbd_icp_auto:
            icp = icp_point_to_plane(depths[i - 1], depths[i], intr, T, strides=ICP_STRIDES)
            if icp.ok and res.T_tgt_src is not None:
                self.check.add(res.T_tgt_src, icp.T_tgt_src)
            if icp.ok and self.use_icp:
                T = icp.T_tgt_src
            elif not icp.ok:
                meta["icp_rejected"].append((i, icp.reason))
        if (
            self.cfg.rgbd_joint_pose
            and res.T_tgt_src is not None
            and (not self.use_icp or (self.cfg.rgbd_joint_with_icp and not self.check.mismatch))
        ):
            joint = joint_pose(
                X,
                uv_t,
                depths[i - 1],
                depths[i],
                intr,
                res.T_tgt_src,
                flow_weight=self.cfg.rgbd_joint_flow_weight,
                strides=ICP_STRIDES,
                inlier_px=self.cfg.ransac_threshold_px,
            )
            if joint.ok:
                T = joint.T_tgt_src
                meta["joint_posed"].append(i)
            else:
                meta["joint_rejected"].append((i, joint.reason))
        if self.cfg.rgbd_odometry:
            ok, T_odo = rgbd_odometry((imgs[i - 1], depths[i - 1]), (imgs[i], depths[i]), intr, T, self.cfg)
            dt, dr = pose_distance(T, T_odo)
            if ok and (res.T_tgt_src is None or (dt < 0.1 and dr < 10.0)):
                T = T_odo
            else:
                meta["odometry_rejected"].append(i)
        return T

    def encode(
        self,
        frames: list[Frame],
        shared_depth: np.ndarray | None = None,  # [H, W] or [h, w], metres
        shared_pose_hint: np.ndarray | None = None,
        shared_confidence: np.ndarray | None = None,  # unused: the sensor's depth has its own
    ) -> SubmapEncoding:
        check_frames(frames, need_depth=True)
        intr = pointmap_intrinsics(frames[0].intrinsics, self.cfg.pointmap_max_side)
        imgs = [resize_image(f.image, intr) for f in frames]
        depths = [self._depth(f.depth, intr) for f in frames]
        if shared_depth is not None:
            sd = self._depth(np.asarray(shared_depth, dtype=np.float32), intr)
            holes = ~np.isfinite(depths[0]) & np.isfinite(sd)
            depths[0][holes] = sd[holes]
        meta: dict = {
            "pnp_inliers": [],
            "pnp_failed": [],
            "odometry_rejected": [],
            "direct_rejected": [],
            "icp_rejected": [],
            "icp_direct_rejected": [],
            "joint_rejected": [],
            "joint_posed": [],
            "degenerate": False,
        }
        n = len(frames)
        T_local = np.tile(np.eye(4), (n, 1, 1))
        for i in range(1, n):
            T_i_prev = self._frame_to_frame(frames, imgs, depths, i, intr, meta)
            T_chain = T_local[i - 1] @ invert_T(T_i_prev)  # T_0_i
            T_local[i] = T_chain
            direct = self.use_icp and self.cfg.rgbd_icp_direct and i > 1
            if direct and not meta["joint_posed"]:
                # keyframe-to-keyframe: frame i straight against frame 0 stops the chained drift (not
                # after joint poses: depth alone from frame 0 undid their gain, docs/results.md, session 8)
                icp = icp_point_to_plane(depths[0], depths[i], intr, invert_T(T_chain), strides=ICP_STRIDES)
                if icp.ok:
                    T_local[i] = invert_T(icp.T_tgt_src)
                else:
                    meta["icp_direct_rejected"].append((i, icp.reason))
            if self.cfg.rgbd_odometry and i > 1:
                ok, T_i_0 = rgbd_odometry(
                    (imgs[0], depths[0]), (imgs[i], depths[i]), intr, invert_T(T_chain), self.cfg
                )
                T_direct = invert_T(T_i_0)
                dt, dr = pose_distance(T_chain, T_direct)
                if ok and dt < 0.05 + 0.2 * np.linalg.norm(T_chain[:3, 3]) and dr < 5.0:
                    T_local[i] = T_direct
                else:
                    meta["direct_rejected"].append(i)
        if meta["pnp_failed"] and len(meta["pnp_failed"]) == n - 1:
            meta["degenerate"] = True
            log.warning(
                "rgbd encoder: no frame of submap %s could be registered by PnP (textureless "
                "or missing depth?); poses come from odometry alone",
                [f.index for f in frames],
            )
        points = np.stack([depth_to_points(intr.K, d) for d in depths]).astype(np.float32)
        conf = np.stack(
            [
                np.where(np.isfinite(d), np.where(depth_edge_mask(d), EDGE_CONFIDENCE, 1.0), 0.0)
                for d in depths
            ]
        ).astype(np.float32)
        meta["depth_stats"] = [robust_depth_stats(d) for d in depths]
        meta["scale_source"] = "metric"
        meta["pnp_icp_rotation_ratio"] = self.check.ratio
        meta["use_icp"] = self.use_icp
        return SubmapEncoding([f.index for f in frames], T_local, points, conf, intr, meta)


register_encoder("rgbd", lambda cfg, flow: RGBDEncoder(cfg, flow))
