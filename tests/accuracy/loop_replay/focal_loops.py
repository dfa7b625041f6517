"""Session 11 measuring tool (docs/results.md, "Mono loops and the focal length, session 11"), not a test:
the loops of a mono run kept by ``exp.py`` against the ground truth, and replays of its graph with loops
left out or re-weighted.

``PYTHONPATH=. python focal_loops.py PKL table``            per loop: N, ray sigmas, rotation error vs the
                                                              truth, its chi2 / 3N and DCS weight after the run
``PYTHONPATH=. python focal_loops.py PKL VARIANT ...``      keyframe ATE (Sim(3), cm) before / after the batch

``PYTHONPATH=. python focal_loops.py PKL eighths VARIANT ...``  the same, and the RMS error of each eighth
                                                              of the keyframes (cm, after the batch)

Variants: ``asis``; ``off`` (no loop); ``oracleX`` (loops whose rotation is more than X deg from the truth
left out); ``dropI-M`` (loop I-M left out); ``neffK`` (information of at most K points); ``keepI-M`` (its
removal after optimisation undone); ``A+B`` (both); ``ownC`` (DCS Phi = C x the loop's own-fit chi2);
``phiC`` (DCS Phi = C x 3N instead of the run's).
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))  # replay.py
from replay import gt_origin, gt_pose_at, is_loop, kf_poses, load_kept, replay  # noqa: E402

from gsslam.geometry import invert_T, split_sim3, transform_points  # noqa: E402

st, gt, KEY2SUB = load_kept(sys.argv[1])
ts = st["ts"]


def gt_at(t):
    return gt_pose_at(gt, t)


def rot_err(i, m, T_i_m):
    """Degrees between the loop's rotation and the truth's (free of the unknown mono scale)."""
    Gi, Gm = gt_origin(st, gt, i), gt_origin(st, gt, m)  # anchored at keyframes with ground truth
    R_gt = (invert_T(Gi) @ Gm)[:3, :3]
    R = split_sim3(T_i_m)[0]
    return float(np.degrees(np.arccos(np.clip((np.trace(R_gt.T @ R) - 1) / 2, -1, 1))))


def ray_chi2(X_i, X_m, T, s_ray, s_perp):
    d = X_i - transform_points(T, X_m)
    u = X_i / np.linalg.norm(X_i, axis=1, keepdims=True)
    a = np.sum(d * u, 1)
    p = d - a[:, None] * u
    return float(np.sum(a**2) / s_ray**2 + np.sum(p**2) / s_perp**2)


def loop_specs():
    return [op[2] for op in st["replay"] if op[0] == "factor" and is_loop(op[2])]


def ij(sp):
    return KEY2SUB[sp[1][0]], KEY2SUB[sp[1][1]]


def table():
    err = {(lc["i"], lc["m"]): rot_err(lc["i"], lc["m"], lc["T_i_m"]) for lc in st["loopc"]}
    S = st["S_before"]
    kept = {(lc["i"], lc["m"]) for lc in st["loopc"]}
    spr = spreads() if st["loopc"] and "view_i" in st["loopc"][0] else {}
    from gsslam.loop.extent import lateral_extent_rel
    print(" i-m    N   s_ray/thr s_perp/thr  rot_err  est_err  chi2/3N  dcs_w  kept  spread  extent")
    for sp in loop_specs():
        i, m = ij(sp)
        Xi, Xm, s_ray, s_perp = sp[1][2], sp[1][3], sp[1][4], sp[1][5]
        phi = sp[2].get("dcs_phi", 0.0) * 3 * len(Xi)
        T_est = invert_T(S[i]) @ S[m]
        c2 = ray_chi2(Xi, Xm, T_est, s_ray, s_perp)
        w = 1.0 if phi <= 0 or c2 <= phi else (2 * phi / (phi + c2)) ** 2
        lc = next((x for x in st["loopc"] if (x["i"], x["m"]) == (i, m)), None)
        thr = lc["thr"] if lc else np.nan
        e = err.get((i, m), np.nan)
        print(f"{i:2d}-{m:2d} {len(Xi):4d}  {s_ray / thr:6.3f}   {s_perp / thr:6.3f}   {e:6.2f}  "
              f"{rot_err(i, m, T_est):6.2f}  "
              f"{c2 / (3 * len(Xi)):7.2f}  {w:5.2f}  {(i, m) in kept}  {spr.get((i, m), np.nan):6.2f}  "
              f"{lateral_extent_rel(Xi):6.3f}")


def spreads(min_points=12):
    """(i, m) -> the loop's view-pair rotation spread, deg: the largest angle between the Sim(3) rotation
    fitted to one view pair's inliers (pairs of >= ``min_points``) and the loop's pooled rotation; 0 with
    fewer than two such pairs (session 12; needs a run kept with the loops' views)."""
    from gsslam.geometry import umeyama

    def rot(T):
        return T[:3, :3] / np.cbrt(np.linalg.det(T[:3, :3]))

    def angle(Ra, Rb):
        return float(np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1))))

    out = {}
    for lc in st["loopc"]:
        pair = lc["view_i"].astype(np.int64) * 1_000_003 + lc["view_m"].astype(np.int64)
        R = [rot(umeyama(lc["X_m"][pair == p], lc["X_i"][pair == p], with_scale=True))
             for p in np.unique(pair) if (pair == p).sum() >= min_points]
        out[(lc["i"], lc["m"])] = max((angle(rot(lc["T_i_m"]), r) for r in R), default=0.0) if len(R) > 1 else 0.0
    return out


def keep(pairs):
    """The run's log with the removals of loops ``pairs`` left out (handles = order of the factor ops)."""
    ops, handles, out = st["replay"], {}, []
    for op in ops:
        if op[0] == "factor":
            handles[len(handles)] = ij(op[2]) if is_loop(op[2]) else None
    for op in ops:
        if op[0] == "remove":
            op = ("remove", [h for h in op[1] if handles.get(int(h)) not in pairs])
        out.append(op)
    return {**st, "replay": out}


def run_variant(name):
    """``A+B``: variants applied together (each a loop map, or ``keepI-M,..``: its removal undone)."""
    s, maps = st, []
    for part in name.split("+"):
        if part.startswith("keep"):
            s = keep({tuple(int(x) for x in p.split("-")) for p in part[4:].split(",")})
        else:
            maps.append(variant(part).get("loop_map", lambda sp: sp))

    def loop_map(sp):
        for m in maps:
            sp = m(sp)
            if sp is None:
                return None
        return sp

    return replay(s, loop_map=loop_map)


def variant(name):
    if name == "asis":
        return dict()
    if name == "off":
        return dict(loop_map=lambda sp: None)
    if name.startswith("oracle"):
        lim = float(name[6:])
        bad = set()
        for lc in st["loopc"]:
            if rot_err(lc["i"], lc["m"], lc["T_i_m"]) > lim:
                bad.add((lc["i"], lc["m"]))
        return dict(loop_map=lambda sp: None if ij(sp) in bad else sp)
    if name.startswith("drop"):
        pairs = {tuple(int(x) for x in p.split("-")) for p in name[4:].split(",")}
        return dict(loop_map=lambda sp: None if ij(sp) in pairs else sp)
    if name.startswith("neff"):  # the loop's information capped at K independent points: sigmas x sqrt(N / K)
        K = float(name[4:])

        def m(sp):
            f = np.sqrt(max(1.0, len(sp[1][2]) / K))
            a = sp[1]
            return (sp[0], (*a[:4], a[4] * f, a[5] * f, *a[6:]), sp[2])
        return dict(loop_map=m)
    if name.startswith("own"):  # DCS Phi = C x the loop's chi2 under its own Sim(3) fit (C = 1 unless given)
        c = float(name[3:] or 1)
        from gsslam.geometry import umeyama

        def m(sp):
            Xi, Xm, s_ray, s_perp = sp[1][2], sp[1][3], sp[1][4], sp[1][5]
            c0 = ray_chi2(Xi, Xm, umeyama(Xm, Xi, with_scale=True), s_ray, s_perp)
            return (sp[0], sp[1], {**sp[2], "dcs_phi": c * c0 / (3 * len(Xi))})
        return dict(loop_map=m)
    if name.startswith("spread") or name.startswith("spw"):
        # session 12: the loop's view-pair spread (gsslam/loop/view_spread.py; kept runs with views only):
        # spreadX leaves out loops whose spread is above X deg, spwX multiplies their sigmas by spread / X
        x = float(name[6:] if name.startswith("spread") else name[3:])
        sp_of = spreads()

        def m(sp):
            d = sp_of.get(ij(sp), 0.0)
            if name.startswith("spread"):
                return None if d > x else sp
            f = max(1.0, d / x)
            a = sp[1]
            return (sp[0], (*a[:4], a[4] * f, a[5] * f, *a[6:]), sp[2])
        return dict(loop_map=m)
    if name.startswith("extw") or name.startswith("ext"):
        # session 12: the loop's lateral extent (gsslam/loop/extent.py): extX leaves out loops whose
        # points' second principal std / median range is below X, extwX multiplies their sigmas by X / it
        from gsslam.loop.extent import lateral_extent_rel
        w = name.startswith("extw")
        x = float(name[4:] if w else name[3:])

        def m(sp):
            e = lateral_extent_rel(sp[1][2])
            if not w:
                return None if e < x else sp
            f = max(1.0, x / max(e, 1e-9))
            a = sp[1]
            return (sp[0], (*a[:4], a[4] * f, a[5] * f, *a[6:]), sp[2])
        return dict(loop_map=m)
    if name.startswith("phi"):
        c = float(name[3:])
        return dict(loop_map=lambda sp: (sp[0], sp[1], {**sp[2], "dcs_phi": c}))
    raise SystemExit(f"unknown variant {name}")


if __name__ == "__main__":
    args = sys.argv[2:]
    if args[:1] == ["table"]:
        table()
    elif args[:1] == ["eighths"]:
        from gsslam.eval.ate import compute_ate
        from gsslam.types import Trajectory

        for v in args[1:]:
            a, b, be = run_variant(v)
            P = kf_poses(be.values(), st)
            ks = sorted(P)
            res, _ = compute_ate(gt, Trajectory(np.array([ts[k] for k in ks]), np.stack([P[k] for k in ks])), align="sim3")
            e = 100 * np.asarray(res.errors)
            parts = " ".join(f"{np.sqrt(np.mean(e[j] ** 2)):.2f}" for j in np.array_split(np.arange(len(e)), 8))
            print(f"{v}: kf ATE {b:.3f}, eighths {parts}", flush=True)
    else:
        for v in args:
            a, b, be = run_variant(v)
            print(f"{v}: kf ATE before batch {a:.3f} after batch {b:.3f}", flush=True)
