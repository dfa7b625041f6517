"""Session 6 measuring tool (docs/results.md, "Mono loops, session 6"), not a test: per-loop errors against
the ground truth and replays of a run kept by exp.py with the mono loop weight changed.

``PYTHONPATH=. python rexp2.py PKL loops``            per loop: inliers, RMS, sigma, error of the loop itself
``PYTHONPATH=. python rexp2.py PKL VARIANT ...``      keyframe ATE before / after the batch per variant
``PYTHONPATH=. python rexp2.py PKL submaps VARIANT``  per-submap rotation / scale error vs ground truth
"""
import sys
from pathlib import Path

import gtsam
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))  # replay.py
from replay import gt_origin, gt_pose_at, has_gt, is_loop, load_kept, replay  # noqa: E402

from gsslam.factors import make_relative_point_factor, to_matrix  # noqa: E402
from gsslam.factors.loop_points import relative_point_residual  # noqa: E402
from gsslam.factors._lie import fill, read_transform  # noqa: E402
from gsslam.geometry import invert_T, transform_points, umeyama  # noqa: E402
from gsslam.graph.keys import submap_key  # noqa: E402

st, gt, KEY2SUB = load_kept(sys.argv[1])
ts = st["ts"]


def gt_at(t):
    return gt_pose_at(gt, t)


mpl = []  # metres per local unit of each submap, from its keyframe translations
for fi, L in zip(st["frame_indices"], st["T_local_cam"]):
    ok = [j for j, f in enumerate(fi) if has_gt(gt, ts[f])] or list(range(len(fi)))  # keyframes with truth
    G = np.stack([gt_at(ts[fi[j]]) for j in ok])
    Grel = np.array([invert_T(G[0]) @ g for g in G])
    Lrel = np.array([invert_T(L[ok[0]]) @ L[j] for j in ok])
    mpl.append(np.linalg.norm(Grel[:, :3, 3], axis=1).sum() / np.linalg.norm(Lrel[:, :3, 3], axis=1).sum())


def G_of(k):  # the submap's local frame -> metres (its first keyframe is its origin)
    g = gt_origin(st, gt, k, mpl[k]).copy()  # anchored at its first keyframe with ground truth
    g[:3, :3] *= mpl[k]
    return g


def sim3_parts(T):
    s = np.cbrt(np.linalg.det(T[:3, :3]))
    R = T[:3, :3] / s
    ang = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
    return s, R, ang


def loop_error(i, m, T_i_m, depth_i):
    """Measured T_i_m against the ground truth: rotation deg, log-scale %, translation / median depth."""
    Tgt = invert_T(G_of(i)) @ G_of(m)
    E = np.linalg.inv(Tgt) @ T_i_m
    s, R, ang = sim3_parts(E)
    return ang, 100 * np.log(s), np.linalg.norm(E[:3, 3]) / depth_i


def rms_of(Xi, Xm, T=None):
    if T is None:
        T = umeyama(Xm, Xi, with_scale=True)
    return float(np.sqrt(np.mean(np.sum((transform_points(T, Xm) - Xi) ** 2, 1))))


def loop_specs():
    return [op[2] for op in st["replay"] if op[0] == "factor" and is_loop(op[2])]


def show_loops():
    dep = st["enc_depth_med"]
    print(" i   m     N   rms/thr  sigma/thr   rot_err_deg  scale_err_%  trans_err/depth   thr")
    for lc in st["loopc"]:
        i, m = lc["i"], lc["m"]
        r = rms_of(lc["X_i"], lc["X_m"], lc["T_i_m"])
        ang, ds, dt = loop_error(i, m, lc["T_i_m"], dep[i])
        sig = max(r, 0.25 * lc["thr"])
        print(f"{i:2d} {m:3d} {len(lc['X_i']):5d}  {r / lc['thr']:.3f}    {sig / lc['thr']:.3f}      "
              f"{ang:6.3f}      {ds:6.2f}      {dt:.4f}      {lc['thr']:.4f}")


def rel_factor(sp, sigma, noise=None):
    Xi, Xm = sp[1][2], sp[1][3]
    f = make_relative_point_factor(sp[1][0], sp[1][1], Xi, Xm, sigma)
    if noise is None:
        return f
    w = np.full(len(Xi), 1.0 / sigma) if np.isscalar(sigma) else 1.0 / sigma

    def error(this, values, H):
        ka, kb = this.keys()
        r, JA, JB = relative_point_residual(read_transform(values, ka, "sim3"), read_transform(values, kb, "sim3"),
                                            Xi, Xm, w, H is not None)
        fill(H, 0, JA)
        fill(H, 1, JB)
        return r

    return gtsam.CustomFactor(noise(3 * len(Xi)), [sp[1][0], sp[1][1]], error)


def thr_of(sp):
    i = KEY2SUB[sp[1][0]]
    return 0.02 * st["enc_depth_med"][i]  # loop.inlier_threshold_rel x median depth (approx. of the record's)


def variant(name):
    """loop_map for a variant name."""
    if "_" in name and name != "asis_gt":  # BASE_KERNELc: a base variant's factor under a robust kernel on the loop's norm (3N)
        base, kern = name.split("_")
        inner = variant(base)["loop_map"]
        kind = kern.rstrip("0123456789.")
        c = float(kern[len(kind):])
        from gsslam.graph.factor_specs import build_factor

        def m(sp):
            f0 = build_factor(inner(sp))
            n = 3 * len(sp[1][2])
            e = {"dcs": lambda: gtsam.noiseModel.mEstimator.DCS.Create(c * n),
                 "cauchy": lambda: gtsam.noiseModel.mEstimator.Cauchy.Create(c * np.sqrt(n))}[kind]()
            keys = list(f0.keys())

            def error(this, values, H):
                if H is None:
                    return f0.unwhitenedError(values)
                lin = f0.linearize(values)
                A, b = lin.jacobian()
                H[0] = A[:, :7]
                H[1] = A[:, 7:]
                return -b
            return gtsam.CustomFactor(gtsam.noiseModel.Robust.Create(e, gtsam.noiseModel.Unit.Create(n)), keys, error)
        return dict(loop_map=m)
    if name == "asis":
        return dict()
    if name == "off":
        return dict(loop_map=lambda sp: None)
    if name == "old":  # the world-unit factor at graph.loop_sigma_m
        return dict(loop_map=lambda sp: ("point", (*sp[1][:4], 0.05), {}))
    if name.startswith("neff"):  # information of at most K independent points
        K = float(name[4:])

        def m(sp):
            Xi, Xm = sp[1][2], sp[1][3]
            r = max(rms_of(Xi, Xm), 0.25 * thr_of(sp))
            return ("relative_point", (*sp[1][:4], r * np.sqrt(max(1.0, len(Xi) / K))), {})
        return dict(loop_map=m)
    if name.startswith("fixrel"):  # sigma = f x the inlier distance
        f = float(name[6:])
        return dict(loop_map=lambda sp: ("relative_point", (*sp[1][:4], f * thr_of(sp)), {}))
    if name.startswith("dcs"):  # dynamic covariance scaling on the loop's chi2, Phi = c x its dimension 3N
        c = float(name[3:])

        def m(sp):
            Xi, Xm = sp[1][2], sp[1][3]
            r = max(rms_of(Xi, Xm), 0.25 * thr_of(sp))
            e = gtsam.noiseModel.mEstimator.DCS.Create(c * 3 * len(Xi))
            return rel_factor(sp, r, noise=lambda n: gtsam.noiseModel.Robust.Create(e, gtsam.noiseModel.Unit.Create(n)))
        return dict(loop_map=m)
    if name.startswith("bray"):  # both point maps' rays: cov = (C(u_a) + C(R u_b)) / 2 at the measured loop
        f = float(name[4:] or 1)
        from gsslam.factors.loop_rays import ray_point_residual

        def m(sp):
            Xi, Xm = sp[1][2], sp[1][3]
            T = umeyama(Xm, Xi, with_scale=True)
            d = Xi - transform_points(T, Xm)
            u = Xi / np.linalg.norm(Xi, axis=1, keepdims=True)
            par = np.sum(d * u, 1)
            perp = d - par[:, None] * u
            fl = 0.25 * thr_of(sp)
            s_ray = f * max(np.sqrt(np.mean(par ** 2)), fl)
            s_perp = f * max(np.sqrt(np.mean(np.sum(perp ** 2, 1)) / 2), fl)
            R = T[:3, :3] / np.cbrt(np.linalg.det(T[:3, :3]))
            ub = Xm / np.linalg.norm(Xm, axis=1, keepdims=True) @ R.T
            C = lambda uu: s_perp ** 2 * np.eye(3)[None] + (s_ray ** 2 - s_perp ** 2) * uu[:, :, None] * uu[:, None, :]
            Cov = 0.5 * (C(u) + C(ub))
            ev, V = np.linalg.eigh(Cov)
            W = np.einsum("nij,nj,nkj->nik", V, 1 / np.sqrt(ev), V)  # Cov^-1/2
            def error(this, values, H):
                ka, kb = this.keys()
                r, JA, JB = ray_point_residual(read_transform(values, ka, "sim3"), read_transform(values, kb, "sim3"), Xi, Xm, W, H is not None)
                fill(H, 0, JA); fill(H, 1, JB)
                return r
            return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3 * len(Xi)), [sp[1][0], sp[1][1]], error)
        return dict(loop_map=m)
    if name.startswith("zray"):  # ray sigmas proportional to each point's depth (relative errors), x f
        f = float(name[4:] or 1)

        def m(sp):
            Xi, Xm = sp[1][2], sp[1][3]
            d = Xi - transform_points(umeyama(Xm, Xi, with_scale=True), Xm)
            z = np.linalg.norm(Xi, axis=1)
            u = Xi / z[:, None]
            par = np.sum(d * u, 1) / z
            perp = (d - np.sum(d * u, 1)[:, None] * u) / z[:, None]
            fl = 0.25 * thr_of(sp) / np.median(z)
            s_ray = max(np.sqrt(np.mean(par ** 2)), fl)
            s_perp = max(np.sqrt(np.mean(np.sum(perp ** 2, 1)) / 2), fl)
            return ("ray_point", (*sp[1][:4], f * s_ray * z, f * s_perp * z), {})
        return dict(loop_map=m)
    if name.startswith("ray"):  # sigma along / across the ray from the loop's residuals, x f
        f = float(name[3:] or 1)

        def m(sp):
            Xi, Xm = sp[1][2], sp[1][3]
            d = Xi - transform_points(umeyama(Xm, Xi, with_scale=True), Xm)
            u = Xi / np.linalg.norm(Xi, axis=1, keepdims=True)
            par = np.sum(d * u, 1)
            perp = d - par[:, None] * u
            fl = 0.25 * thr_of(sp)
            s_ray = max(np.sqrt(np.mean(par ** 2)), fl)
            s_perp = max(np.sqrt(np.mean(np.sum(perp ** 2, 1)) / 2), fl)
            return ("ray_point", (*sp[1][:4], f * s_ray, f * s_perp), {})
        return dict(loop_map=m)
    if name.startswith("mul"):  # the inlier-RMS sigma x a constant
        f = float(name[3:])

        def m(sp):
            Xi, Xm = sp[1][2], sp[1][3]
            return ("relative_point", (*sp[1][:4], f * max(rms_of(Xi, Xm), 0.25 * thr_of(sp))), {})
        return dict(loop_map=m)
    if name.startswith("share"):  # information of the loops that share a submap divided among them
        from collections import Counter
        cnt = Counter([lc["m"] for lc in st["loopc"]])

        def m(sp):
            Xi, Xm = sp[1][2], sp[1][3]
            r = max(rms_of(Xi, Xm), 0.25 * thr_of(sp))
            return ("relative_point", (*sp[1][:4], r * np.sqrt(cnt[KEY2SUB[sp[1][1]]])), {})
        return dict(loop_map=m)
    if name.startswith("gm"):  # Geman-McClure on the loop's norm, c x sqrt(3N)
        c = float(name[2:])

        def m(sp):
            Xi, Xm = sp[1][2], sp[1][3]
            r = max(rms_of(Xi, Xm), 0.25 * thr_of(sp))
            e = gtsam.noiseModel.mEstimator.GemanMcClure.Create(c * np.sqrt(3 * len(Xi)))
            return rel_factor(sp, r, noise=lambda n: gtsam.noiseModel.Robust.Create(e, gtsam.noiseModel.Unit.Create(n)))
        return dict(loop_map=m)
    if name.startswith("huber") or name.startswith("cauchy"):  # per-loop kernel on the whole loop's norm
        kind = "huber" if name.startswith("huber") else "cauchy"
        k = float(name[len(kind):])

        def m(sp):
            Xi, Xm = sp[1][2], sp[1][3]
            r = max(rms_of(Xi, Xm), 0.25 * thr_of(sp))
            # the kernel on sqrt(chi2) of the loop: k in units of sqrt(3N) (its expected norm)
            kk = k * np.sqrt(3 * len(Xi))
            e = gtsam.noiseModel.mEstimator.Huber.Create(kk) if kind == "huber" else gtsam.noiseModel.mEstimator.Cauchy.Create(kk)
            return rel_factor(sp, r, noise=lambda n: gtsam.noiseModel.Robust.Create(e, gtsam.noiseModel.Unit.Create(n)))
        return dict(loop_map=m)
    if name == "asis_gt":  # the loop replaced by its exact value, same weight
        def m(sp):
            i, mm = KEY2SUB[sp[1][0]], KEY2SUB[sp[1][1]]
            Tim = invert_T(G_of(i)) @ G_of(mm)
            return (sp[0], (sp[1][0], sp[1][1], transform_points(Tim, sp[1][3]), sp[1][3], *sp[1][4:]), sp[2])
        return dict(loop_map=m)
    raise SystemExit(f"unknown variant {name}")


def submap_errors(be):
    S = [to_matrix(be.values().atSimilarity3(submap_key(k))) for k in range(len(mpl))]
    G = [G_of(k) for k in range(len(mpl))]
    A = umeyama(np.stack([s[:3, 3] for s in S]), np.stack([g[:3, 3] for g in G]), with_scale=True)
    out = []
    for k in range(len(mpl)):
        E = np.linalg.inv(G[k]) @ A @ S[k]
        s, R, ang = sim3_parts(E)
        out.append((ang, 100 * np.log(s)))
    return out


if __name__ == "__main__":
    args = sys.argv[2:]
    if args[:1] == ["loops"]:
        show_loops()
    elif args[:1] == ["loo"]:  # leave one loop out (zero weight), loops j0..j1: keyframe ATE before the batch
        specs = loop_specs()
        j0, j1 = int(args[1]), int(args[2])
        for j in range(j0, min(j1, len(specs))):
            target = specs[j]
            a, _, _ = replay(st, loop_map=lambda sp, t=target: None if sp is t else sp, batch=False)
            i, mm = KEY2SUB[target[1][0]], KEY2SUB[target[1][1]]
            print(f"without loop {i}-{mm} (N {len(target[1][2])}): kf ATE before batch {a:.3f}", flush=True)
    elif args[:1] == ["chi"]:  # per loop after the replay (and batch): chi2 / 3N at its sigma
        for v in args[1:]:
            a, b, be = replay(st, **variant(v))
            print(f"{v}: kf ATE {a:.3f} / {b:.3f}")
            S = {k: to_matrix(be.values().atSimilarity3(submap_key(k))) for k in range(len(mpl))}
            for lc in st["loopc"]:
                i, m = lc["i"], lc["m"]
                Tim = invert_T(S[i]) @ S[m]
                r = rms_of(lc["X_i"], lc["X_m"], Tim)
                r0 = rms_of(lc["X_i"], lc["X_m"], lc["T_i_m"])
                sig = max(r0, 0.25 * lc["thr"])
                ang = loop_error(i, m, lc["T_i_m"], 1.0)[0]
                ang_est = loop_error(i, m, Tim, 1.0)[0]
                print(f"  {i:2d}-{m:2d} N {len(lc['X_i']):4d} chi2/3N {(r / sig) ** 2:7.2f}  loop rot err {ang:5.2f}  est rot err {ang_est:5.2f}")
    elif args[:1] == ["submaps"]:
        rows = {}
        for v in args[1:]:
            a, b, be = replay(st, **variant(v))
            rows[v] = submap_errors(be)
            print(f"{v}: kf ATE {a:.3f} / {b:.3f}")
        print("k  " + "  ".join(f"{v:>16s}" for v in rows))
        for k in range(len(mpl)):
            print(f"{k:2d} " + "  ".join(f"{rows[v][k][0]:6.2f}d {rows[v][k][1]:+6.2f}%" for v in rows))
    else:
        for v in args:
            a, b, _ = replay(st, **variant(v))
            print(f"{v}: kf ATE before batch {a:.3f} after batch {b:.3f}", flush=True)
