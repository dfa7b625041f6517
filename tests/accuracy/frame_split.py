"""Where the error of the frames between keyframes comes from: a ``track_probe.py --dump`` file split.

    PYTHONPATH=. python tests/accuracy/frame_split.py run.npz [run2.npz ...]

For every non-keyframe ``f`` tracked against keyframe ``k`` (its written pose is ``T_w_k T_k_f``, the
keyframe's final estimate composed with the tracked relative pose) the position error after the SE(3)
alignment of the whole trajectory (as the ATE) is compared with two what-ifs:

- ``kf only``: the keyframe's estimate composed with the TRUE relative pose (perfect frame tracking);
- ``rel only``: the true keyframe pose composed with the ESTIMATED relative pose (perfect keyframes).

and the relative pose's own error (cm / deg; ``T_k_f`` estimated vs true), by distance from the keyframe.
Prints the RMS over the non-keyframes and the ATE of each what-if trajectory. Not a test: a measuring
tool (docs/results.md, "RGB-D frames between keyframes, session 9").
"""

from __future__ import annotations

import sys

import numpy as np

from gsslam.eval.ate import ate_from_pairs
from gsslam.geometry import invert_T, so3_log


def _rms(x: np.ndarray) -> float:
    return 100 * float(np.sqrt(np.mean(np.asarray(x) ** 2))) if len(x) else float("nan")


def split(path: str) -> dict:
    d = np.load(path)
    idx, est, gt, ref, kfs = d["idx"], d["est"], d["gt"], d["ref"], set(d["keyframes"].tolist())
    pos = {int(i): k for k, i in enumerate(idx)}
    al = ate_from_pairs(gt[:, :3, 3], est[:, :3, 3], "se3").alignment
    A = al.apply_poses(est)  # [N, 4, 4] aligned estimates
    kf_only, rel_only, actual, rel_cm, rel_deg = [], [], [], [], []
    traj_kf, traj_rel = A[:, :3, 3].copy(), A[:, :3, 3].copy()
    for n, (i, k) in enumerate(zip(idx.tolist(), ref.tolist(), strict=True)):
        if i in kfs or k < 0 or k not in pos:
            continue
        j = pos[k]
        G_kf = invert_T(gt[j]) @ gt[n]  # true T_k_f
        E_kf = invert_T(est[j]) @ est[n]  # written T_k_f
        D = invert_T(G_kf) @ E_kf
        rel_cm.append(np.linalg.norm(D[:3, 3]))
        rel_deg.append(np.degrees(np.linalg.norm(so3_log(D[:3, :3]))))
        actual.append(np.linalg.norm(A[n, :3, 3] - gt[n, :3, 3]))
        p_kf = (A[j] @ G_kf)[:3, 3]
        p_rel = (gt[j] @ E_kf)[:3, 3]
        kf_only.append(np.linalg.norm(p_kf - gt[n, :3, 3]))
        rel_only.append(np.linalg.norm(p_rel - gt[n, :3, 3]))
        traj_kf[n], traj_rel[n] = p_kf, p_rel
    ate = lambda P: 100 * ate_from_pairs(gt[:, :3, 3], P, "se3").stats.rmse  # noqa: E731
    is_kf = np.array([i in kfs for i in idx.tolist()])
    return {
        "frames": len(idx),
        "non_keyframes": len(actual),
        "ate_cm": round(ate(est[:, :3, 3]), 3),
        "ate_keyframes_cm": round(_rms(np.linalg.norm(A[is_kf, :3, 3] - gt[is_kf, :3, 3], axis=1)), 3),
        "ate_with_true_relative_cm": round(ate(traj_kf), 3),
        "ate_with_true_keyframes_cm": round(ate(traj_rel), 3),
        "nonkf_err_cm": round(_rms(actual), 3),
        "nonkf_kf_only_cm": round(_rms(kf_only), 3),
        "nonkf_rel_only_cm": round(_rms(rel_only), 3),
        "relative_err_cm_median": round(100 * float(np.median(rel_cm)), 3),
        "relative_err_cm_rms": round(_rms(rel_cm), 3),
        "relative_err_deg_median": round(float(np.median(rel_deg)), 3),
    }


def main(argv: list[str]) -> int:
    for path in argv:
        print(path, split(path))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
