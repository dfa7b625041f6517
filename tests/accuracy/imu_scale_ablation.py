"""Where a mono + IMU run's scale error comes from: the visual graph of teddy-200 mono (no IMU, map off)
is captured once, then the IMU stage (IMU *synthesized* from the mocap) is added offline, initialised
on all keyframes and solved by batch LM, with parts of the visual side replaced by the mocap's.

    PYTHONPATH=.:tests python tests/accuracy/imu_scale_ablation.py [--tie world] [--cache F] [--set k=v]

Rows: the captured visual graph; one Sim(3) over keyframe poses that are the visual ones, the mocap's,
or mixes (visual rotations + mocap positions and the reverse). ``--tie world`` measures the tie's
position residual in world units as before session 5 (docs/results.md, "IMU in the run, session 5").
"""

import argparse
import logging
import pickle
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from gsslam.config import load_config
from gsslam.datasets.tum import TumRgbdDataset
from gsslam.factors import to_gtsam, to_matrix
from gsslam.geometry import umeyama
from gsslam.graph.backend import Backend
from gsslam.graph.factor_specs import build_factor, spec
from gsslam.graph.imu import B
from gsslam.graph.keys import submap_key
from gsslam.graph.noise import gauge_prior_sigmas
from gsslam.slam.imu_stage import ImuStage
from gsslam.slam.pipeline import Pipeline
from gsslam.slam.plugins import Plugin

TEDDY = Path(__file__).parents[2].parent / "shared" / "data" / "rgbd_dataset_freiburg3_teddy"


def capture(ds, cfg) -> dict:
    """Run mono without IMU; keep the live factor specs, the submap estimates and keyframe anchors."""

    class Times(Plugin):
        def __init__(self):
            self.t = {}

        def on_keyframe(self, e):
            self.t[e.frame_index] = float(e.timestamp)

    rec = Times()
    pipe = Pipeline(cfg, ds.intrinsics)
    pipe.add_plugin(rec)
    for i in range(len(ds)):
        pipe.process(ds[i])
    pipe.close_chain()
    pipe.finish()
    g = pipe.chains[0].graph
    live, h = {}, 0
    for op in g.backend.replay_log():
        if op[0] == "factor":
            live[h] = (op[1], op[2])
            h += 1
        elif op[0] == "remove":
            for x in op[1]:
                live.pop(int(x), None)
    vals = g.backend.values()
    est = {int(k): vals.atSimilarity3(k).matrix() for k in vals.keys() if chr(int(k) >> 56) == "s"}
    anchors = {f: g.keyframe_anchor(f) for f in g.keyframe_poses()}
    return dict(
        live=live, est=est, anchors=anchors, times=rec.t, poses=g.keyframe_poses(), gauge=g.gauge_handle
    )


def rigid(T):
    out = T.copy()
    out[:3, :3] /= np.cbrt(np.linalg.det(T[:3, :3]))
    return out


class AnchoredGraph:
    """What ImuStage needs of a SubmapGraph: keyframes anchored on Sim(3) variables of a backend."""

    def __init__(self, backend, anchors, gauge):
        self.backend, self.anchors, self.gauge_handle = backend, anchors, gauge

    def keyframe_anchor(self, f):
        k, L = self.anchors[f]
        return k, L.copy()

    def keyframe_poses(self):
        v = self.backend.values()
        return {f: rigid(to_matrix(v.atSimilarity3(k)) @ L) for f, (k, L) in sorted(self.anchors.items())}

    def remove_factor(self, h):
        self.backend.remove_factors([h])


def world_unit_tie():
    """Before session 5: the tie's translation residual in world units, its sigma in metres."""
    import gsslam.factors.keyframe_tie as kt
    import gsslam.graph.imu as gi

    new = kt.keyframe_tie_residual

    def residual(S, X, L, T_body_cam, group, want_jac=True):
        r, J_S, J_X = new(S, X, L, T_body_cam, group, want_jac)
        s = float(S[2])
        e = r[3:] * s
        r[3:] = e
        if want_jac:
            if group == "sim3":
                J_S[3:6, 6] += e / s  # undo the -e/s of the submap-unit residual, then scale back
            J_S[3:6] *= s
            J_X[3:6] *= s
        return r, J_S, J_X

    kt.keyframe_tie_residual = residual
    old_add = gi.add_keyframe_tie

    def add(graph, f, T_cam_body, rot_sigma, trans_sigma):  # no conversion by the submap's scale
        return old_add(
            graph,
            f,
            T_cam_body,
            rot_sigma,
            trans_sigma * float(graph.backend.estimate(graph.keyframe_anchor(f)[0]).scale()),
        )

    import gsslam.slam.imu_stage as st

    st.add_keyframe_tie = add


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tie", choices=["submap", "world"], default="submap")
    ap.add_argument("--cache", default=None, help="pickle of the captured visual graph (made if missing)")
    ap.add_argument(
        "--set",
        nargs="*",
        default=[],
        help="overrides, e.g. imu.tie_trans_sigma=0.0025",
    )
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    if args.tie == "world":
        world_unit_tie()
    cfg = load_config(None, ["mapper.enabled=false"], mode="mono")
    ds = TumRgbdDataset(TEDDY, imu="synthesized", with_depth=False)
    if args.cache and Path(args.cache).is_file():
        D = pickle.load(open(args.cache, "rb"))
    else:
        D = capture(ds, cfg)
        if args.cache:
            pickle.dump(D, open(args.cache, "wb"))
    cfg = load_config(None, ["mapper.enabled=false", "imu.enabled=true", *args.set], mode="mono")
    gt = ds.ground_truth()
    slerp = Slerp(gt.timestamps, Rotation.from_matrix(gt.poses[:, :3, :3]))

    def gt_at(t):
        T = np.eye(4)
        T[:3, :3] = slerp([t]).as_matrix()[0]
        T[:3, 3] = [np.interp(t, gt.timestamps, gt.poses[:, k, 3]) for k in range(3)]
        return T

    times = D["times"]
    kfs = [f for f in sorted(D["anchors"]) if gt.timestamps[0] <= times[f] <= gt.timestamps[-1]]
    Y = np.stack([gt_at(times[f])[:3, 3] for f in kfs])

    def evaluate(label, graph):
        st = ImuStage(cfg, ds.imu(), ds.T_body_cam)
        st.times = dict(times)
        st._initialize(graph)  # on all keyframes at once (the run: after the first submap)
        graph.backend.update()
        graph.backend.refine_batch()
        P = graph.keyframe_poses()
        X = np.stack([P[f][:3, 3] for f in kfs])
        T = umeyama(X, Y, with_scale=True)
        R = umeyama(X, Y, with_scale=False)
        se3 = np.sqrt(((X @ R[:3, :3].T + R[:3, 3] - Y) ** 2).sum(1).mean())
        ba = graph.backend.estimate(B(kfs[-1])).accelerometer()
        s = np.cbrt(np.linalg.det(T[:3, :3]))
        print(
            f"{label:48s} scale error {abs(s - 1) * 100:5.2f} %  SE(3) ATE {se3 * 100:5.2f} cm  "
            f"final accel bias {np.round(ba, 3)}"
        )

    be = Backend.from_config(cfg.graph)
    handles = {
        h: be.add_factor(build_factor(sp), name, spec=sp) for h, (name, sp) in sorted(D["live"].items())
    }
    for k, M in D["est"].items():
        be.add_value(k, to_gtsam(M, "sim3"))
    be.update()
    evaluate(f"visual graph ({args.tie}-unit tie)", AnchoredGraph(be, D["anchors"], handles[D["gauge"]]))

    P0 = D["poses"]
    X0 = np.stack([P0[f][:3, 3] for f in kfs])
    G = np.linalg.inv(umeyama(X0, Y, with_scale=True))  # mocap -> visual world
    Lgt = {f: rigid(G @ gt_at(times[f])) for f in kfs}
    rows = {"visual poses": {f: P0[f] for f in kfs}, "mocap poses": Lgt}
    rows["visual rotations + mocap positions"] = {
        f: np.block([[P0[f][:3, :3], Lgt[f][:3, 3:]], [Lgt[f][3:]]]) for f in kfs
    }
    rows["mocap rotations + visual positions"] = {
        f: np.block([[Lgt[f][:3, :3], P0[f][:3, 3:]], [P0[f][3:]]]) for f in kfs
    }
    for name, Ls in rows.items():
        be = Backend.from_config(cfg.graph)
        be.add_value(submap_key(0), to_gtsam(np.eye(4), "sim3"))
        s0 = spec("sim3_prior", submap_key(0), gauge_prior_sigmas(cfg.graph))
        h = be.add_factor(build_factor(s0), "gauge prior s0", spec=s0)
        be.update()
        evaluate(f"one Sim(3), {name}", AnchoredGraph(be, {f: (submap_key(0), Ls[f]) for f in kfs}, h))


if __name__ == "__main__":
    main()
