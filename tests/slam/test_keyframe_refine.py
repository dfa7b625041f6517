"""Keyframe refinement (gsslam.slam.keyframe_refine): corrections inside submaps, on a synthetic RGB-D chain.

Three metric submaps of 3 keyframes in front of a plane wall; frames 6, 7, 8 (submap 2) look at what
frames 0, 1, 2 (submap 0) saw, frame 5 (submap 1) at what 1 and 7 saw; five loops say so. The encoder's
local pose of frame 1 is 7 mm off: the submap graph can only move whole submaps (the loops disagree: a
compromise); with one pose per keyframe, frame 1 moves (two loops of three on frames 1, 5, 7 say it is
the odd one out; a single loop could not tell which of its two keyframes is wrong).
"""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.config import GraphConfig
from gsslam.geometry import invert_T, so3_exp
from gsslam.graph.submap_graph import SubmapGraph
from gsslam.loop.icp_loop import adjoint
from gsslam.slam.keyframe_refine import RefineSettings, refine_keyframes
from gsslam.types import CameraIntrinsics, SubmapEncoding

INTR = CameraIntrinsics(fx=20.0, fy=20.0, cx=7.5, cy=5.5, width=16, height=12)
X_POS = [0.0, 0.1, 0.2, 0.3, 0.2, 0.1, 0.0, 0.1, 0.2, 0.3]  # frame 7 is where frame 1 was
ERR = np.array([0.006, -0.002, 0.003])  # the local pose error of frame 1 in submap 0 (m)


def truth(f: int) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = so3_exp(np.array([0.0, 0.05 * np.sin(f), 0.0]) if f not in (1, 7) else np.array([0.0, 0.02, 0.0]))
    T[:3, 3] = [X_POS[f], 0.02 * (f % 2) if f not in (1, 7) else 0.0, 0.0]
    return T


def wall_points(T_wc: np.ndarray) -> np.ndarray:  # [h, w, 3] camera points on the plane z_world = 2
    u, v = np.meshgrid(np.arange(INTR.width), np.arange(INTR.height))
    d = np.stack([(u - INTR.cx) / INTR.fx, (v - INTR.cy) / INTR.fy, np.ones_like(u, float)], -1)
    s = (2.0 - T_wc[2, 3]) / (d @ T_wc[:3, :3].T)[..., 2]
    return d * s[..., None]


def chain(error: bool = True):
    encs = []
    for i in range(3):
        frames = list(range(3 * i, 3 * i + 4))
        T0 = invert_T(truth(frames[0]))
        L = np.stack([T0 @ truth(f) for f in frames])
        if error and i == 0:
            L[1, :3, 3] += ERR
        pts = np.stack([wall_points(truth(f)) for f in frames])
        encs.append(SubmapEncoding(frames, L, pts, np.ones(pts.shape[:3]), INTR))
    return encs


def loop_points(encs, i, v, m, u):
    """Points of frame ``frames[v]`` of submap i, in submap i's and submap m's local frames (seen from view u)."""
    fv, fu = encs[i].frame_indices[v], encs[m].frame_indices[u]
    W = wall_points(truth(fv)).reshape(-1, 3) @ truth(fv)[:3, :3].T + truth(fv)[:3, 3]  # world
    out = []
    for s, j, f in ((i, v, fv), (m, u, fu)):
        T = encs[s].T_local_cam[j] @ invert_T(truth(f))  # the submap's (possibly wrong) view of the world
        out.append(W @ T[:3, :3].T + T[:3, 3])
    return out


def build(encs, loop=True):
    g = SubmapGraph(GraphConfig(), monocular=False)
    for e in encs:
        g.add_submap(e)
    if loop:  # frames 6, 7, 8 (submap 2) come back to 0, 1, 2 (submap 0), 5 (submap 1) sees what 1 and 7 saw
        for i, v, m, u in ((2, 0, 0, 0), (2, 1, 0, 1), (2, 2, 0, 2), (2, 1, 1, 2), (1, 2, 0, 1)):
            X_i, X_m = loop_points(encs, i, v, m, u)
            g.add_loop(i, m, X_i, X_m, sigma=0.002)
    g.update()
    g.refine_batch()
    return g


def refine(g, encs, sigma=0.003):
    return refine_keyframes(
        [e.frame_indices for e in encs], [e.T_local_cam for e in encs],
        [g.submap_pose(i) for i in range(len(encs))], g.backend.live_specs(), RefineSettings(sigma, sigma),
        depths=[e.depths for e in encs], Ks=[e.intrinsics.K for e in encs],
    )  # fmt: skip


def pos_err(P: dict, f: int) -> float:
    return float(np.linalg.norm(P[f][:3, 3] - truth(f)[:3, 3]))


def test_loop_corrects_the_keyframe_inside_its_submap():
    encs = chain()
    g = build(encs)
    before = g.keyframe_poses()
    res = refine(g, encs)
    assert res.moved == {"submap_alignment": 2, "point": 7}  # 2 adjacency + 5 loops
    # measured: frame 1 off by 7.0 mm in the submap graph, 2.6 mm refined; all keyframes RMS 3.7 -> 2.3 mm
    assert pos_err(before, 1) > 0.006
    assert pos_err(res.poses, 1) < 0.5 * pos_err(before, 1)
    rms = [np.sqrt(np.mean([pos_err(P, f) ** 2 for f in range(10)])) for P in (before, res.poses)]
    assert rms[1] < 0.75 * rms[0]
    assert res.error_after < res.error_before


def test_without_loops_the_submap_graph_optimum_is_kept():
    encs = chain()
    g = build(encs, loop=False)
    before = g.keyframe_poses()
    res = refine(g, encs)
    assert res.moved == {"submap_alignment": 2, "point": 2}
    for f, T in before.items():  # every tie at zero: the same poses (measured: < 1e-9 m)
        assert np.abs(res.poses[f] - T).max() < 1e-6


def test_loop_points_go_to_the_keyframe_that_saw_them():
    from gsslam.slam.keyframe_refine import SubmapFrames

    encs = chain(error=False)
    fr = SubmapFrames([e.frame_indices for e in encs], [e.T_local_cam for e in encs],
                 [e.depths for e in encs], [e.intrinsics.K for e in encs])  # fmt: skip
    for j in range(4):
        X = encs[1].points_cam[j].reshape(-1, 3) @ encs[1].T_local_cam[j][:3, :3].T + encs[1].T_local_cam[j][:3, 3]
        views = fr.views_of(1, X)
        assert (views == j).mean() > 0.5  # other views see the same wall: ties go to any of them
        assert np.all(np.isin(views, range(4)))


@pytest.mark.parametrize("seed", [0, 1])
def test_icp_loop_information_follows_the_keyframes(seed):
    """An ICP loop moved to its keyframe pair: at keyframe poses x = S L, the whitened residual equals
    the submap-level one to first order (the information is carried by the adjoint of L_b)."""
    import gtsam

    from gsslam.factors import make_relative_pose_factor

    rng = np.random.default_rng(seed)

    def rand_pose(s):
        T = np.eye(4)
        T[:3, :3] = so3_exp(rng.normal(scale=s, size=3))
        T[:3, 3] = rng.normal(scale=s, size=3)
        return T

    La, Lb, Si, Sm = (rand_pose(0.5) for _ in range(4))
    Z = invert_T(Si) @ Sm @ rand_pose(1e-3)  # a measurement 1 mrad / 1 mm off
    A = rng.normal(size=(6, 6))
    info = A @ A.T + 6 * np.eye(6)
    f_sub = make_relative_pose_factor(0, 1, Z, info, 0.0, "pose3")
    Ad = adjoint(Lb)
    f_kf = make_relative_pose_factor(0, 1, invert_T(La) @ Z @ Lb, Ad.T @ info @ Ad, 0.0, "pose3")
    v_sub, v_kf = gtsam.Values(), gtsam.Values()
    v_sub.insert(0, gtsam.Pose3(Si))
    v_sub.insert(1, gtsam.Pose3(Sm))
    v_kf.insert(0, gtsam.Pose3(Si @ La))
    v_kf.insert(1, gtsam.Pose3(Sm @ Lb))
    e_sub, e_kf = f_sub.error(v_sub), f_kf.error(v_kf)
    assert e_sub > 1e-6
    assert abs(e_kf - e_sub) < 0.02 * e_sub  # measured: ~1e-3 relative


@pytest.mark.slow
def test_run_with_keyframe_refinement(bundled_tum):
    """End to end on the bundled TUM frames (no loops there): the refined poses are the run's keyframe
    poses and equal the submap graph's; a mono run skips the stage."""
    from gsslam.config import load_config
    from gsslam.datasets.base import open_dataset
    from gsslam.slam.pipeline import Pipeline

    for mode in ("rgbd", "mono"):
        ds = open_dataset("tum", bundled_tum, **({"with_depth": False} if mode == "mono" else {}))
        cfg = load_config(None, ["mapper.enabled=false", "graph.keyframe_refine=true"], mode=mode)
        pipe = Pipeline(cfg, ds.intrinsics)
        for i in range(30):
            pipe.process(ds[i])
        pipe.finish()
        chain = pipe.chains[0]
        kf = pipe.keyframe_poses()
        if mode == "mono":
            assert chain.refined_poses is None
            continue
        assert "keyframe refine" in pipe.stage_seconds
        assert set(chain.refined_poses) == set(kf)
        for f, T in kf.items():
            assert np.abs(T - chain.world_pose(chain.refined_poses[f])).max() < 1e-12
            assert np.abs(T - chain.world_pose(chain.graph.keyframe_pose(f))).max() < 1e-6  # measured ~1e-9


def test_relative_registration_moves_to_its_keyframe_and_keeps_its_owner_submap():
    """A relative registration of submap 1's keyframe 3 against owner submap 0 becomes a factor between the
    owner's submap variable and the keyframe's own variable: zero where the keyframe sits at the measured
    pose in the owner's frame, non-zero 1 cm away."""
    import gtsam

    from gsslam.graph.factor_specs import spec
    from gsslam.graph.keys import keyframe_key, submap_key
    from gsslam.slam.keyframe_refine import SubmapFrames, _move

    L0 = np.stack([np.eye(4)] * 3)
    L1 = np.stack([np.eye(4)] * 3)
    L1[1, :3, 3] = [0.1, 0.0, 0.0]
    fr = SubmapFrames([[0, 1, 2], [2, 3, 4]], [L0, L1])
    T_owner_cam = np.eye(4)
    T_owner_cam[:3, 3] = [0.5, 0.2, 0.0]
    kind, args, kw = spec("relative_registration", submap_key(0), submap_key(1), L1[1:2], T_owner_cam[None],
                          np.eye(6)[None] * 1e4, "sim3")  # fmt: skip
    g = _move(kind, args, kw, fr)
    assert g is not None and g.size() == 1
    S0 = np.eye(4)
    S0[:3, 3] = [1.0, 0.0, 0.0]
    for off, want_zero in ((0.0, True), (0.01, False)):
        v = gtsam.Values()
        v.insert(submap_key(0), gtsam.Pose3(S0))
        T = S0 @ T_owner_cam
        T[0, 3] += off
        v.insert(keyframe_key(3), gtsam.Pose3(T))
        assert (g.error(v) < 1e-12) == want_zero
