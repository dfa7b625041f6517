"""Where the mono trajectory error comes from, submap by submap: scale links and translation directions.

    PYTHONPATH=. python tests/accuracy/chain_links.py run s2blur --loops off [--set key=value ...] [--tag T]
    PYTHONPATH=. python tests/accuracy/chain_links.py show /tmp/chain_links/s2blur_off.pkl [--variants ...]

``run`` plays a suite row in process (map off, as ``gsslam batch`` does) and keeps the chain's graph log
(``Backend.replay_log``), every submap's local poses, its frame-0 and frame-K depths and confidences,
the ground-truth poses and (where the dataset has it) the ground-truth depth of those frames.

``show`` prints per submap: ``r`` (least-squares ratio of the encoder's local keyframe translations to
the ground truth's: the submap's translation scale as chained), ``link`` (r_i / r_{i-1}: one chaining
step's error), ``d0`` / ``dK`` (median ratio of the submap's frame-0 / frame-K depth to the ground
truth's, in the same chained units; ``d/r`` is then the submap's depth-to-baseline error), ``dir``
(mean angle between local and true translation directions, deg), ``rot`` (mean local rotation error,
deg) and ``g2``; then keyframe ATE (Sim(3), cm, after the final batch) of graph replays in which only
what a variant names is replaced by the ground truth:

- ``asis``: the log as run;
- ``gtlink``: every scale link (the scale factor's measurement, the shared frame's adjacency points and
  the initial value) set so that each submap's translation scale equals submap 0's;
- ``gtdir``: every submap's local translation directions replaced by the true ones (norms kept);
- ``gtlink+gtdir``: both;
- ``chain`` / ``chain_gtlink``: no graph, the submaps composed through their shared frames.

Not a test: a measuring tool (docs/results.md, "Mono scale chain, session 10").
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import pickle
import sys
from pathlib import Path

import numpy as np

OUT = os.environ.get("CHAIN_LINKS_OUT", "/tmp/chain_links")
BLUR = {"shutter": 0.5, "exposure_amp": 0.25, "exposure_period": 150}
DATA = os.environ.get("GSSLAM_DATA", "../shared/data")
TEDDY = f"{DATA}/rgbd_dataset_freiburg3_teddy"
FBF = dict(base="tum", pattern="fbf", pause_every=97, pause_len=15, jump_every=151, jump_len=4, seed=0)
ROWS = {  # the tracking suite's rows (gsslam/run/suites/tracking.yaml): (dataset, path, kwargs, frames)
    "s2blur": ("playback", TEDDY, dict(base="tum", pattern="fbfbf", stride=2, degrade=BLUR), 300),
    "s2blur7m": (  # teddy200_s2_blur_7scenes_mono
        "playback",
        TEDDY,
        dict(base="tum", pattern="fbfbf", stride=2, degrade=BLUR,
             misregister=dict(baseline_m=0.025, focal_scale=1.114, report="depth")),
        300,
    ),
    "s3blur": ("playback", TEDDY, dict(base="tum", pattern="fbfbfbf", stride=3, degrade=BLUR), 300),
    "fbf": ("playback", TEDDY, FBF, None),
    "teddy200": ("tum", TEDDY, dict(with_depth=False), None),  # as the runner opens a mono TUM row
    "synth800": (
        "synthetic",
        None,
        dict(n_frames=800, width=320, height=240, trajectory="loop", seed=5),
        None,
    ),
    "kitti01": ("kitti", f"{DATA}/kitti_odometry", dict(sequence="01"), None),
    "kitti06": ("kitti", f"{DATA}/kitti_odometry", dict(sequence="06"), None),
}


def _angle(a, b) -> float:
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na < 1e-12 or nb < 1e-12:
        return float("nan")
    return float(np.degrees(np.arccos(np.clip(a @ b / (na * nb), -1, 1))))


def run(a) -> None:
    from gsslam.config import load_config
    from gsslam.datasets.base import loader, open_dataset
    from gsslam.factors import to_matrix
    from gsslam.slam.pipeline import Pipeline

    dsname, path, kw, nmax = ROWS[a.seq]
    ds = open_dataset(dsname, path, **kw) if path else loader(dsname)(None, **kw)
    loops = "true" if a.loops == "on" else "false"
    cfg = load_config(None, ["mapper.enabled=false", f"loop.enabled={loops}", *a.overrides], mode="mono")
    pipe = Pipeline(cfg, ds.intrinsics)
    n = len(ds) if nmax is None else min(nmax, len(ds))
    gt_depth = {}
    for i in range(n):
        f = ds[i]
        gt_depth[f.index] = f.depth
        pipe.process(dataclasses.replace(f, depth=None))
    pipe.close_chain()
    ch = pipe.chains[0]
    st = {"seq": a.seq, "loops": a.loops, "set": a.overrides, "chains": len(pipe.chains)}
    st["replay"] = [
        (op[0], op[1], to_matrix(op[2])) if op[0] == "value" and not isinstance(op[2], np.ndarray) else op
        for op in ch.graph.backend.replay_log()
    ]
    pipe.finish()
    st["stretch"] = ch.graph.submap_stretches() if hasattr(ch.graph, "submap_stretches") else None
    st["kf_after"] = pipe.keyframe_poses()
    st["fr_after"] = pipe.frame_poses()
    st["ts"], st["gt"] = pipe.timestamps, ds.ground_truth()
    st["frame_indices"] = [list(e.frame_indices) for e in ch.encodings]
    st["T_local_cam"] = [e.T_local_cam for e in ch.encodings]
    st["K_enc"] = [e.intrinsics.K for e in ch.encodings]
    st["depth0"] = [e.points_cam[0, ..., 2].astype(np.float32) for e in ch.encodings]
    st["depthK"] = [e.points_cam[-1, ..., 2].astype(np.float32) for e in ch.encodings]
    st["conf0"] = [e.confidence[0].astype(np.float32) for e in ch.encodings]
    st["confK"] = [e.confidence[-1].astype(np.float32) for e in ch.encodings]
    st["meta"] = [
        {k: v for k, v in e.meta.items() if isinstance(v, (int, float, str, bool))} for e in ch.encodings
    ]
    import cv2

    def small(fi, shape):
        d = gt_depth.get(fi)
        return (
            None
            if d is None
            else cv2.resize(np.asarray(d, np.float32), shape[::-1], interpolation=cv2.INTER_NEAREST)
        )

    st["gt_depth0"] = [small(fi[0], d.shape) for fi, d in zip(st["frame_indices"], st["depth0"])]
    st["gt_depthK"] = [small(fi[-1], d.shape) for fi, d in zip(st["frame_indices"], st["depthK"])]
    st["loops_metrics"] = pipe.loop_stage.metrics()
    os.makedirs(OUT, exist_ok=True)
    name = f"{OUT}/{a.seq}_{a.loops}{('_' + a.tag) if a.tag else ''}.pkl"
    with open(name, "wb") as fh:
        pickle.dump(st, fh)
    print(name)


# -- analysis ------------------------------------------------------------------------------------
def gt_pose(st, f):
    from gsslam.geometry import invert_T  # noqa: F401

    gt = st["gt"]
    ts = st["ts"][f]
    j = int(np.argmin(np.abs(gt.timestamps - ts)))
    return gt.poses[j] if abs(gt.timestamps[j] - ts) < 0.02 else None


def per_submap(st) -> list[dict]:
    from gsslam.geometry import invert_T, so3_log

    rows = []
    for k, (fi, L) in enumerate(zip(st["frame_indices"], st["T_local_cam"])):
        # the reference: frame 0, or the first keyframe that has ground truth (the first frames of a
        # TUM sequence come before its ground truth starts)
        Gs = [gt_pose(st, f) for f in fi]
        j0 = next((j for j, G in enumerate(Gs) if G is not None), None)
        num = den = 0.0
        dirs, rots, tg = [], [], []
        for j in range(1, len(fi)):
            G = Gs[j]
            if G is None or j0 is None or j <= j0:
                tg.append(None)
                continue
            Tg = invert_T(Gs[j0]) @ G
            tg.append(Tg if j0 == 0 else None)
            Te = invert_T(L[j0]) @ L[j]
            te = Te[:3, 3]
            num += np.linalg.norm(te) * np.linalg.norm(Tg[:3, 3])
            den += np.linalg.norm(Tg[:3, 3]) ** 2
            dirs.append(_angle(te, Tg[:3, 3]))
            rots.append(np.degrees(np.linalg.norm(so3_log(Te[:3, :3].T @ Tg[:3, :3]))))
        r = num / den if den > 0 else float("nan")

        def dscale(z, g):
            if g is None:
                return float("nan")
            ok = np.isfinite(z) & (z > 0) & np.isfinite(g) & (g > 0)
            return float(np.exp(np.median(np.log(z[ok] / g[ok])))) if ok.sum() > 10 else float("nan")

        nan = float("nan")
        rows.append(dict(
            r=r, d0=dscale(st["depth0"][k], st["gt_depth0"][k]),
            dK=dscale(st["depthK"][k], st["gt_depthK"][k]),
            dir=float(np.nanmean(dirs)) if dirs else nan, rot=float(np.mean(rots)) if rots else nan,
            g2=st["meta"][k].get("dense_scale_correction", float("nan")), T_gt=tg,
            par=st["meta"][k].get("parallax_deg", float("nan")),
        ))  # fmt: skip
    return rows


def _scales(rows) -> np.ndarray:
    """Per-submap translation scales; a submap without ground truth takes its neighbour's."""
    r = np.array([row["r"] for row in rows])
    for k in list(range(len(r))) + list(range(len(r) - 1, -1, -1)):
        if not np.isfinite(r[k]):
            near = [r[j] for j in (k - 1, k + 1) if 0 <= j < len(r) and np.isfinite(r[j])]
            r[k] = near[0] if near else 1.0
    return r


def corrected_locals(st, rows, gtdir: bool, gtb: bool = False) -> list[np.ndarray]:
    out = []
    for L, row in zip(st["T_local_cam"], rows):
        L = L.copy()
        if gtb:  # translations consistent with the submap's own depth (frame K's; frame 0's is the
            c = row["dK"] / row["r"]  # previous submap's): r -> dK
            L[:, :3, 3] *= c if np.isfinite(c) else 1.0
        if gtdir:
            for j, Tg in enumerate(row["T_gt"], 1):
                if Tg is not None and np.linalg.norm(Tg[:3, 3]) > 1e-9:
                    L[j, :3, 3] = np.linalg.norm(L[j, :3, 3]) * Tg[:3, 3] / np.linalg.norm(Tg[:3, 3])
        out.append(L)
    return out


def replay(st, rows, gtlink: bool, gtdir: bool, loops: bool = True, knobs: dict | None = None, gtb=False):
    sys.path.insert(0, str(Path(__file__).parent / "loop_replay"))

    from gsslam.config import load_config
    from gsslam.factors import to_gtsam, to_matrix
    from gsslam.graph.backend import Backend
    from gsslam.graph.factor_specs import build_factor
    from gsslam.graph.keys import submap_key

    keyidx = {submap_key(k): k for k in range(len(rows))}
    r = _scales(rows)
    Ls = corrected_locals(st, rows, gtdir, gtb)
    Lold = st["T_local_cam"]

    def find_local(M):
        for k, L in enumerate(Lold):
            for j in range(len(L)):
                if np.allclose(L[j], M, atol=1e-12):
                    return Ls[k][j]
        return M

    cfg = load_config(None, ["mapper.enabled=false"], mode="mono").graph
    be = Backend.from_config(cfg)
    kn = knobs or {}
    for op in st["replay"]:
        if op[0] == "factor":
            kind, args, kwargs = op[2]
            if kind in ("relative_point", "ray_point", "stretched_ray_point") and not loops:
                continue
            if kind == "point" and int(args[0]) > int(args[1]) and not loops:
                continue

            if kind == "scale" and "ss" in kn:  # the scale factor's sigma
                args = (*args[:3], kn["ss"])
            if kind == "point" and "adj" in kn and int(args[0]) < int(args[1]):  # adjacency sigma x adj
                args = (*args[:4], args[4] * kn["adj"])
            if kind == "stretch_prior" and "st" in kn:  # the translation stretch's prior sigma
                args = (args[0], kn["st"])
            if kind == "flow" and "flow" in kn:  # flow factor weights x flow
                kwargs = dict(kwargs, weight=np.asarray(kwargs["weight"]) * kn["flow"])
            if kind == "scale" and gtlink:
                b = keyidx[int(args[1])]
                args = (args[0], args[1], args[2] + np.log(r[b - 1] / r[b]), *args[3:])
            if kind == "point" and keyidx.get(int(args[1]), -1) == keyidx.get(int(args[0]), -9) + 1:
                b = keyidx[int(args[1])]
                Z, Z2 = Lold[b - 1][-1], Ls[b - 1][-1]
                Xa = (args[2] - Z[:3, 3]) @ Z[:3, :3]  # back in the shared camera
                Xa = Xa @ Z2[:3, :3].T + Z2[:3, 3]
                Xb = args[3] * (r[b] / r[b - 1] if gtlink else 1.0)
                args = (args[0], args[1], Xa, Xb, *args[4:])
            if kind == "submap_alignment":
                args = (args[0], args[1], find_local(args[2]), *args[3:])
            if kind == "flow":
                kwargs = dict(kwargs, L_a=find_local(kwargs["L_a"]), L_b=find_local(kwargs["L_b"]))
            if "stretch" in kn:  # the run's graph with a translation stretch per submap (sigma kn["stretch"])
                kind, args, kwargs = _stretched_spec(kind, args, kwargs, keyidx, Ls, "noflow" not in kn)
            sp = (kind, args, kwargs)
            be.add_factor(build_factor(sp), op[1], spec=sp)
        elif op[0] == "value" and isinstance(op[2], np.ndarray) and op[2].ndim == 1:  # a stretch
            be.add_value(int(op[1]), op[2])
        elif op[0] == "value":
            k = keyidx[int(op[1])]
            if k == 0:
                S = op[2]
            else:
                Sp = (
                    to_matrix(be.values().atSimilarity3(submap_key(k - 1)))
                    if be.has_value(submap_key(k - 1))
                    else None
                )
                S = op[2]
                if Sp is not None and (gtlink or gtdir or gtb):
                    c = np.cbrt(np.linalg.det(Sp[:3, :3]))
                    link = c * (r[k - 1] / r[k] if gtlink else 1.0)
                    S = Sp @ Ls[k - 1][-1] @ np.diag([link / c] * 3 + [1.0])
            be.add_value(int(op[1]), to_gtsam(S, "sim3"))
            if "stretch" in kn:
                from gsslam.graph import stretch as gs

                be.add_value(gs.stretch_key(k), gs.initial_value())
                sp = gs.prior_spec(k, kn["stretch"])
                be.add_factor(build_factor(sp), None, spec=sp)
        elif op[0] == "remove":
            try:
                be.remove_factors([int(h) for h in op[1]])
            except Exception:  # a loop left out above
                pass
        elif op[0] == "update":
            try:
                be.update(int(op[1]))
            except Exception as e:  # noqa: BLE001
                print("update failed", e)
    be.refine_batch()
    vals = be.values()
    S = [to_matrix(vals.atSimilarity3(submap_key(k))) for k in range(len(rows))]
    from gsslam.graph.stretch import local_pose

    Ls = [np.stack([local_pose(vals, k, L) for L in Lk]) for k, Lk in enumerate(Ls)]  # with a stretch
    return kf_ate(st, S, Ls), np.array([np.cbrt(np.linalg.det(s[:3, :3])) for s in S])


def _stretched_spec(kind, args, kwargs, keyidx, Ls, flow: bool = True):
    """A logged plain factor spec as its translation-stretch twin (gsslam.graph.stretch)."""
    from gsslam.graph.stretch import stretch_key

    if kind == "submap_alignment":
        return "stretched_alignment", (args[0], args[1], stretch_key(keyidx[int(args[0])]), *args[2:]), kwargs
    if kind not in ("point", "flow"):
        return kind, args, kwargs
    a, b = keyidx.get(int(args[0]), -9), keyidx.get(int(args[1]), -9)
    if kind == "point" and b == a + 1:  # adjacency: the offset is frame K's camera in submap a
        o = Ls[a][-1][:3, 3]
        return "stretched_point", (args[0], args[1], stretch_key(a), args[2] - o, o, *args[3:]), kwargs
    if kind == "flow" and flow:
        kw = {k: v for k, v in kwargs.items() if k != "group"}
        return "stretched_flow", (args[0], args[1], stretch_key(a), stretch_key(b), *args[2:]), kw
    return kind, args, kwargs


def kf_ate(st, S, Ls) -> float:
    from gsslam.eval.ate import compute_ate
    from gsslam.types import Trajectory

    P = {}
    for k, (fi, L) in enumerate(zip(st["frame_indices"], Ls)):
        for j, f in enumerate(fi):
            if f in P:
                continue
            T = S[k] @ L[j]
            T = T.copy()
            T[:3, :3] /= np.cbrt(np.linalg.det(T[:3, :3]))
            P[f] = T
    ks = sorted(P)
    tr = Trajectory(np.array([st["ts"][k] for k in ks]), np.stack([P[k] for k in ks]))
    res, _ = compute_ate(st["gt"], tr, align="sim3")
    return 100 * res.stats.rmse


def chain(st, rows, gtlink: bool, gtdir: bool = False, gtb: bool = False) -> float:
    r = _scales(rows)
    Ls = corrected_locals(st, rows, gtdir, gtb)
    S = [np.eye(4)]
    for k in range(1, len(rows)):
        c = np.cbrt(np.linalg.det(S[-1][:3, :3])) * (r[k - 1] / r[k] if gtlink else 1.0)
        T = S[-1] @ Ls[k - 1][-1]
        T[:3, :3] /= np.cbrt(np.linalg.det(T[:3, :3]))
        T[:3, :3] *= c
        S.append(T)
    return kf_ate(st, S, Ls)


def show(a) -> None:
    logging.basicConfig(level=logging.ERROR)
    with open(a.pkl, "rb") as fh:
        st = pickle.load(fh)
    rows = per_submap(st)
    print(f"{st['seq']} loops {st['loops']} {st['set']}: {len(rows)} submaps, chains {st['chains']}, "
          f"loops {st['loops_metrics'].get('accepted')}")  # fmt: skip
    print(" sub frames      r      link    d0     dK    dK/r   dir   rot   par   g2")
    prev = None
    links, dirs, dr = [], [], []
    for k, (fi, row) in enumerate(zip(st["frame_indices"], rows)):
        link = row["r"] / prev if prev else float("nan")
        if prev:
            links.append(np.log(link))
        dirs.append(row["dir"])
        dr.append(np.log(row["dK"] / row["r"]))
        print(f" {k:3d} {fi[0]:4d}-{fi[-1]:<4d} {row['r']:7.3f} {link:6.3f} {row['d0']:6.3f} "
              f"{row['dK']:6.3f} {row['dK'] / row['r']:6.3f} {row['dir']:5.2f} {row['rot']:5.2f} "
              f"{row['par']:5.1f} {row['g2']:6.3f}")  # fmt: skip
        prev = row["r"]
    L = np.array(links)[np.isfinite(links)]
    print(f"log link: mean {L.mean():+.4f} std {L.std():.4f} |.| mean {np.abs(L).mean():.4f} "
          f"max {np.abs(L).max():.4f}; log(dK/r) std {np.nanstd(dr):.4f}; "
          f"dir mean {np.nanmean(dirs):.2f} deg")  # fmt: skip
    for v in a.variants:
        if v.startswith("chain"):
            parts = v.split("+")
            ate = chain(st, rows, "gtlink" in parts, "gtdir" in parts, "gtB" in parts)
            print(f"  {v:23s} ATE kf {ate:6.2f} cm (no graph)")
        else:
            parts = v.split("+")
            kn = {p.split("=")[0]: float(p.split("=")[1]) if "=" in p else 1.0 for p in parts}
            ate, s = replay(
                st,
                rows,
                "gtlink" in parts,
                "gtdir" in parts,
                loops="noloops" not in parts,
                knobs=kn,
                gtb="gtB" in parts,
            )
            r = _scales(rows)  # the local translations' scale (gtlink changes only the graph's links)
            if "gtB" in parts:
                r = np.array([row["dK"] for row in rows])
            w = np.log(s * r)  # the world scale of each submap's translations (x the Sim(3) alignment: const)
            w = w[np.isfinite(w)]
            print(
                f"  replay {v:16s} ATE kf {ate:6.2f} cm; world translation scale: std log {w.std():.4f}, "
                f"last/first {np.exp(w[-1] - w[0]):.3f}"
            )


def world_scales(st) -> np.ndarray:
    """Per submap: least-squares ratio of its keyframes' final world translations (from the submap's
    first keyframe, as the run output them) to the ground truth's; NaN without ground truth."""
    P = st["kf_after"]
    out = []
    for fi in st["frame_indices"]:
        pairs = [(P[f], gt_pose(st, f)) for f in fi if f in P]
        pairs = [(a, b) for a, b in pairs if b is not None]
        if len(pairs) < 3:
            out.append(float("nan"))
            continue
        (A0, G0), num, den = pairs[0], 0.0, 0.0
        for A, G in pairs[1:]:
            ta, tg = A[:3, 3] - A0[:3, 3], G[:3, 3] - G0[:3, 3]
            num += np.linalg.norm(ta) * np.linalg.norm(tg)
            den += np.linalg.norm(tg) ** 2
        out.append(num / den if den > 0 else float("nan"))
    return np.array(out)


def spread(a) -> None:
    """All-frame and keyframe ATE (Sim(3), cm) and the spread of the submaps' world translation scale."""
    from gsslam.eval.ate import compute_ate
    from gsslam.types import Trajectory

    for path in a.pkls:
        with open(path, "rb") as fh:
            st = pickle.load(fh)
        fr = st["fr_after"][0] if isinstance(st["fr_after"], tuple) else st["fr_after"]
        ate = {}
        for name, P in (("all", fr), ("kf", st["kf_after"])):
            ks = sorted(P)
            tr = Trajectory(np.array([st["ts"][k] for k in ks]), np.stack([P[k] for k in ks]))
            ate[name] = 100 * compute_ate(st["gt"], tr, align="sim3")[0].stats.rmse
        w = np.log(world_scales(st))
        w = w[np.isfinite(w)]
        t = st.get("stretch")
        ts = "" if t is None or not np.any(t) else f"; stretch std {np.std(t):.4f} max {np.abs(t).max():.3f}"
        print(f"{Path(path).stem:24s} submaps {len(st['frame_indices']):3d} ATE all {ate['all']:.3f} kf "
              f"{ate['kf']:.3f} cm; world translation scale std log {w.std():.4f} (|d| mean "
              f"{np.abs(np.diff(w)).mean():.4f}){ts}")  # fmt: skip


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("seq", choices=sorted(ROWS))
    r.add_argument("--loops", default="off")
    r.add_argument("--set", action="append", default=[], dest="overrides")
    r.add_argument("--tag", default="")
    s = sub.add_parser("show")
    s.add_argument("pkl")
    s.add_argument(
        "--variants",
        nargs="*",
        default=[
            "asis",
            "gtlink",
            "gtdir",
            "gtlink+gtdir",
            "chain",
            "chain+gtlink",
            "chain+gtdir",
            "chain+gtlink+gtdir",
        ],
    )
    sp = sub.add_parser("spread")
    sp.add_argument("pkls", nargs="+")
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    {"run": run, "show": show, "spread": spread}[a.cmd](a)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
