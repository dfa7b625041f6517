"""Session 12 measuring tool (docs/results.md, "Mono loops to the first submap, session 12"), not a test:
each submap of a run kept by ``exp.py`` fitted to the truth by its own Sim(3) (scale and translation from
its keyframes' positions, rotation from their orientations); the floor that fit leaves (the error inside
the submaps), and against those fits the rotation / relative-scale error of the estimate's adjacent
submaps, of the loops as measured and of the estimate on the loops' submap pairs.

``PYTHONPATH=. python submap_links.py PKL ...``
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))  # replay.py
from replay import gt_pose_at, has_gt, load_kept  # noqa: E402

from gsslam.geometry import invert_T, transform_points, umeyama  # noqa: E402


def parts(T):  # Sim(3) error -> (rotation deg, log-scale %)
    s = np.cbrt(np.linalg.det(T[:3, :3]))
    R = T[:3, :3] / s
    return np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))), 100 * np.log(s)


def submap_truths(st, gt):
    """Per submap: its local frame -> world metres (None with fewer than 3 keyframes with truth), and
    the residuals of its keyframe positions under it."""
    ts, out, res = st["ts"], [], []
    for fi, L in zip(st["frame_indices"], st["T_local_cam"]):
        ok = [j for j, f in enumerate(fi) if has_gt(gt, ts[f])]
        if len(ok) < 3:
            out.append(None)
            continue
        G = [gt_pose_at(gt, ts[fi[j]]) for j in ok]
        A, B = np.stack([L[j][:3, 3] for j in ok]), np.stack([g[:3, 3] for g in G])
        T = umeyama(A, B, with_scale=True)
        res.extend(np.linalg.norm(transform_points(T, A) - B, axis=1))
        U, _, Vt = np.linalg.svd(sum(g[:3, :3] @ L[j][:3, :3].T for g, j in zip(G, ok)))
        T = T.copy()
        T[:3, :3] = np.cbrt(np.linalg.det(T[:3, :3])) * (U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt)
        out.append(T)
    return out, np.array(res)


def summary(a):
    a = np.array(a)
    return (f"rot median {np.median(a[:, 0]):.2f} deg, |log scale| median {np.median(np.abs(a[:, 1])):.2f} % "
            f"(max {np.max(np.abs(a[:, 1])):.1f})")


for path in sys.argv[1:]:
    st, gt, _ = load_kept(path)
    Tt, res = submap_truths(st, gt)
    S = st["S_after"]
    adj = [parts(np.linalg.inv(invert_T(Tt[k]) @ Tt[k + 1]) @ invert_T(S[k]) @ S[k + 1])
           for k in range(len(S) - 1) if Tt[k] is not None and Tt[k + 1] is not None]
    lo, le = [], []
    for lc in st["loopc"]:
        i, m = lc["i"], lc["m"]
        if Tt[i] is None or Tt[m] is None:
            continue
        Ttrue = invert_T(Tt[i]) @ Tt[m]
        lo.append(parts(np.linalg.inv(Ttrue) @ lc["T_i_m"]))
        le.append(parts(np.linalg.inv(Ttrue) @ invert_T(S[i]) @ S[m]))
    print(f"{Path(path).name}: within-submap floor {100 * np.sqrt(np.mean(res ** 2)):.3f} cm RMS ({len(res)} keyframes)")
    print("  adjacent submaps, estimate:", summary(adj))
    if lo:
        print("  loops, measured:          ", summary(lo))
        print("  loop pairs, estimate:     ", summary(le))
