"""Accuracy of an encoder's local poses against ground truth (pure functions, for tests/benches)."""

from __future__ import annotations

import numpy as np

from gsslam.geometry import invert_T, so3_log


def local_pose_errors(
    T_local_cam: np.ndarray,  # [K+1, 4, 4] estimated camera -> submap-local (frame 0 = I)
    T_world_cam_gt: np.ndarray,  # [K+1, 4, 4] ground truth
    align_scale: bool,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Per-frame errors of the poses relative to frame 0: (translation [K], rotation deg [K], scale).

    With ``align_scale`` (monocular), the estimated translations are first multiplied by the
    least-squares scale ``s = <t_est, t_gt> / <t_est, t_est>`` over the submap (returned; 1 else).
    """
    gt_rel = np.stack([invert_T(T_world_cam_gt[0]) @ T for T in T_world_cam_gt[1:]])
    est = T_local_cam[1:]
    t_est, t_gt = est[:, :3, 3], gt_rel[:, :3, 3]
    s = 1.0
    if align_scale:
        den = float(np.sum(t_est * t_est))
        s = float(np.sum(t_est * t_gt) / den) if den > 1e-18 else 1.0
    t_err = np.linalg.norm(s * t_est - t_gt, axis=1)
    r_err = np.array(
        [np.degrees(np.linalg.norm(so3_log(e[:3, :3].T @ g[:3, :3]))) for e, g in zip(est, gt_rel)]
    )
    return t_err, r_err, s
