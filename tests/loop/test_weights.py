"""Mono loop weights (gsslam.loop.weights): a loop's per-point sigma is its own inlier residual."""

from __future__ import annotations

import dataclasses

import numpy as np

from gsslam.config import GraphConfig, LoopConfig
from gsslam.geometry import make_T, so3_exp, umeyama
from gsslam.graph.submap_graph import SubmapGraph
from gsslam.loop import LoopConstraint
from gsslam.loop.weights import inlier_rms, loop_point_sigma, loop_weight, ray_sigmas
from helpers.submap_chain import ate, loop_points, make_chain


def _loop(X_m, noise, rng, T=None, thr=0.1):
    T = make_T(so3_exp(np.array([0.1, -0.2, 0.3])), np.array([0.5, 0.0, -1.0]), 1.3) if T is None else T
    X_i = X_m @ T[:3, :3].T + T[:3, 3] + noise * rng.standard_normal(X_m.shape)
    return LoopConstraint(0, 5, X_i, X_m, umeyama(X_m, X_i, with_scale=True), 0.5, 0.8, thr)


def test_sigma_is_the_inlier_rms():
    rng = np.random.default_rng(0)
    lc = _loop(rng.uniform(-1, 1, (400, 3)) + [0, 0, 3], 0.01, rng, thr=0.04)  # floor 0.01 < rms
    cfg = LoopConfig()
    rms = inlier_rms(lc)
    assert 0.014 < rms < 0.019  # 3-D RMS of 0.01 per axis: ~0.0173 (minus the fit's 7 dof)
    assert np.isclose(loop_point_sigma(lc, "mono", cfg), rms)  # submap-i units
    assert loop_point_sigma(lc, "rgbd", cfg) is None  # RGB-D: graph.loop_sigma_m (metric)
    assert loop_point_sigma(lc, "mono", dataclasses.replace(cfg, mono_sigma_from_residual=False)) is None


def test_sigma_has_a_floor_relative_to_the_inlier_distance():
    rng = np.random.default_rng(1)
    exact = _loop(rng.uniform(-1, 1, (50, 3)) + [0, 0, 3], 0.0, rng, thr=0.08)
    assert inlier_rms(exact) < 1e-9
    sigma = loop_point_sigma(exact, "mono", LoopConfig(mono_sigma_min_rel=0.25))
    assert np.isclose(sigma, 0.25 * 0.08)


def test_mono_loop_weighted_by_its_residual_corrects_scale_drift():
    """A Sim(3) loop factor corrects the scale drift of a mono chain, not only a rigid offset."""
    n = 20
    encs, truth = make_chain(n, drift=0.02, seed=0)  # ~2 % scale drift per submap
    rng = np.random.default_rng(1)
    X_i, X_m = loop_points(encs, n - 1, 6, 0, 0, step=2)  # the last frame revisits frame 0
    X_i = X_i + 0.005 * np.median(X_i[:, 2]) * rng.standard_normal(X_i.shape)  # 0.5 % of depth per axis
    thr = LoopConfig().inlier_threshold_rel * float(np.median(X_i[:, 2]))
    lc = LoopConstraint(n - 1, 0, X_i, X_m, umeyama(X_m, X_i, with_scale=True), 0.6, 0.8, thr)

    g = SubmapGraph(GraphConfig(), monocular=True)
    for e in encs:
        g.add_submap(e)
        g.update()

    def scale_error() -> float:  # log of the last submap's scale against the truth
        return abs(float(np.log(g.submap_scales()[-1] / encs[-1].meta["unit"] * encs[0].meta["unit"])))

    ate_open, scale_open = ate(g.keyframe_poses(), truth), scale_error()
    sigma = loop_point_sigma(lc, "mono", LoopConfig())
    g.add_loop(lc.i, lc.m, lc.X_i, lc.X_m, sigma=sigma, local_units=True)
    g.update(extra_iterations=5)
    # measured: scale error 0.378 -> 0.008 (log), ATE 0.448 -> 0.024 (world units, circle radius 5)
    assert scale_open > 0.3
    assert scale_error() < 0.05
    assert ate(g.keyframe_poses(), truth) < ate_open / 8


def test_loop_stage_adds_mono_loops_with_their_residual_sigma(revisit_mono):
    """The pipeline's loop stage hands each mono loop to the graph with its own sigmas, along and across
    the rays (session 6), in submap-i units."""
    from types import SimpleNamespace

    from gsslam.slam.loop_stage import LoopStage

    sm = revisit_mono[0]
    graph = SubmapGraph(GraphConfig(), monocular=True)
    chain = SimpleNamespace(graph=graph)
    stage = LoopStage(LoopConfig(), "mono")
    for s, (enc, img) in enumerate(zip(sm.encodings, sm.images)):
        graph.add_submap(enc)
        graph.update()
        frames = [SimpleNamespace(index=f, gray=g) for f, g in zip(enc.frame_indices, img)]
        stage.after_submap(chain, 0, s, enc, frames)
    loops = [op[2] for op in graph.backend.replay_log() if op[0] == "factor" and op[2][0] == "ray_point"]
    assert loops, "the revisit closes at least one loop, in submap-i units"
    assert not [op for op in graph.backend.replay_log() if op[0] == "factor" and op[2][0] == "point"
                and op[2][1][0] > op[2][1][1]]  # fmt: skip  # no world-unit loop (add_loop(i, m): i > m)
    for _, (_key_i, _key_m, X_i, X_m, sigma, sigma_perp), kw in loops:
        lc = LoopConstraint(1, 0, X_i, X_m, umeyama(X_m, X_i, with_scale=True), 1.0, 1.0, 1.0)
        s_ray, s_perp = ray_sigmas(lc)
        # each is its residual RMS or the common floor (0.25 x 2 % of depth; active across the rays here)
        assert np.isclose(sigma, s_ray, rtol=1e-6) or (sigma > s_ray and np.isclose(sigma, sigma_perp))
        assert np.isclose(sigma_perp, s_perp, rtol=1e-6) or sigma_perp > s_perp
        assert kw["dcs_phi"] == LoopConfig().mono_dcs_phi


# --- session 6: noise along / across the rays, and a DCS kernel per loop ---


def _ray_loop(rng, n=300, sigma_ray=0.03, sigma_perp=0.005, thr=0.015):
    """A loop whose X_i carry depth noise along their rays and pixel noise across them."""
    T = make_T(so3_exp(np.array([0.05, -0.1, 0.02])), np.array([0.2, 0.0, -0.3]), 1.2)
    X_m = rng.uniform([-1.5, -1, 2], [1.5, 1, 5], (n, 3))
    X_i = X_m @ T[:3, :3].T + T[:3, 3]
    u = X_i / np.linalg.norm(X_i, axis=1, keepdims=True)
    perp = rng.standard_normal((n, 3)) * sigma_perp
    perp -= np.sum(perp * u, axis=1, keepdims=True) * u
    X_i = X_i + sigma_ray * rng.standard_normal((n, 1)) * u + perp
    return LoopConstraint(3, 0, X_i, X_m, umeyama(X_m, X_i, with_scale=True), 0.5, 0.8, thr), T


def test_ray_sigmas_split_depth_from_pixel_error():
    rng = np.random.default_rng(5)
    lc, _ = _ray_loop(rng)
    s_ray, s_perp = ray_sigmas(lc)
    assert 0.026 < s_ray < 0.034 and 0.0042 < s_perp < 0.0058  # drawn 0.03 / 0.005
    cfg = LoopConfig()
    w = loop_weight(lc, "mono", cfg)
    assert w.sigma_perp is not None and w.dcs_phi == cfg.mono_dcs_phi
    assert np.isclose(w.sigma, s_ray) and np.isclose(w.sigma_perp, s_perp)
    iso = loop_weight(lc, "mono", dataclasses.replace(cfg, mono_sigma_ray=False))
    assert iso.sigma_perp is None and np.isclose(iso.sigma, inlier_rms(lc))  # session 5's weight
    assert loop_weight(lc, "rgbd", cfg) is None
    assert loop_weight(lc, "mono", dataclasses.replace(cfg, mono_sigma_from_residual=False)) is None
    floor = loop_weight(lc, "mono", dataclasses.replace(cfg, mono_sigma_min_rel=2.5))  # 0.0375 > both sigmas
    assert np.isclose(floor.sigma, 0.0375) and np.isclose(floor.sigma_perp, 0.0375)


def _fit_loop(lc, w) -> np.ndarray:
    """T_i_m recovered by the graph from the loop alone (submap m held at the identity)."""
    import gtsam
    from gtsam.symbol_shorthand import S

    from gsslam.factors import make_ray_point_factor, make_relative_point_factor, to_gtsam, to_matrix

    g = gtsam.NonlinearFactorGraph()
    g.add(gtsam.PriorFactorSimilarity3(S(0), gtsam.Similarity3(), gtsam.noiseModel.Isotropic.Sigma(7, 1e-6)))
    T_m_i = np.linalg.inv(lc.T_i_m)
    if w.sigma_perp is None:
        g.add(make_relative_point_factor(S(1), S(0), lc.X_i, lc.X_m, w.sigma))
    else:
        g.add(make_ray_point_factor(S(1), S(0), lc.X_i, lc.X_m, w.sigma, w.sigma_perp))
    v = gtsam.Values()
    v.insert(S(0), gtsam.Similarity3())
    v.insert(S(1), to_gtsam(T_m_i, "sim3"))
    out = gtsam.LevenbergMarquardtOptimizer(g, v).optimize()
    return np.linalg.inv(to_matrix(out.atSimilarity3(S(1))))  # T_i_m


def _rot_err_deg(T, T_true) -> float:
    R = T[:3, :3] / np.cbrt(np.linalg.det(T[:3, :3]))
    Rt = T_true[:3, :3] / np.cbrt(np.linalg.det(T_true[:3, :3]))
    return float(np.degrees(np.arccos(np.clip((np.trace(R.T @ Rt) - 1) / 2, -1, 1))))


def test_ray_noise_resists_a_depth_distortion():
    """A smooth depth error of the point map (depth x (1 + 0.06 x/z), a tilt) moves points along their
    rays: the isotropic weight tilts the loop's rotation with it, the ray weight less (its sigmas come
    from the residuals of the isotropic fit, which carry part of the tilt across the rays)."""
    rng = np.random.default_rng(6)
    lc, T = _ray_loop(rng, sigma_ray=0.01, sigma_perp=0.003)
    X_i = lc.X_i * (1 + 0.06 * lc.X_i[:, :1] / lc.X_i[:, 2:3])  # along each ray
    lc = dataclasses.replace(lc, X_i=X_i, T_i_m=umeyama(lc.X_m, X_i, with_scale=True))
    cfg = LoopConfig()
    iso = loop_weight(lc, "mono", dataclasses.replace(cfg, mono_sigma_ray=False))
    err_iso = _rot_err_deg(_fit_loop(lc, iso), T)
    err_ray = _rot_err_deg(_fit_loop(lc, loop_weight(lc, "mono", cfg)), T)
    assert err_iso > 1.5  # measured: 1.98 deg
    assert err_ray < 0.85 * err_iso  # measured: 1.54 deg


def test_dcs_down_weights_a_wrong_loop_not_a_good_one():
    """Two loops between the same submaps, one wrong (its points turned 4 deg about their centre), the
    estimate starting at the truth (where the chain puts it). Without a kernel the graph settles between
    them; with DCS (Phi = 3N) the wrong loop ends with a small weight, the good one with full weight."""
    import gtsam
    from gtsam.symbol_shorthand import S

    from gsslam.factors import make_ray_point_factor, to_gtsam, to_matrix

    rng = np.random.default_rng(7)
    good, T = _ray_loop(rng, n=200, sigma_ray=0.01, sigma_perp=0.003)
    bad, _ = _ray_loop(rng, n=200, sigma_ray=0.01, sigma_perp=0.003)
    c = bad.X_i.mean(0)
    X_i = (bad.X_i - c) @ so3_exp(np.array([0.0, np.radians(4.0), 0.0])).T + c
    bad = dataclasses.replace(bad, X_i=X_i, T_i_m=umeyama(bad.X_m, X_i, with_scale=True))

    def solve(phi):
        g = gtsam.NonlinearFactorGraph()
        pin = gtsam.noiseModel.Isotropic.Sigma(7, 1e-6)
        g.add(gtsam.PriorFactorSimilarity3(S(0), gtsam.Similarity3(), pin))
        fs = []
        for lc in (good, bad):
            w = loop_weight(lc, "mono", dataclasses.replace(LoopConfig(), mono_dcs_phi=phi))
            fs.append(
                make_ray_point_factor(S(1), S(0), lc.X_i, lc.X_m, w.sigma, w.sigma_perp, dcs_phi=w.dcs_phi)
            )
            g.add(fs[-1])
        v = gtsam.Values()
        v.insert(S(0), gtsam.Similarity3())
        v.insert(S(1), to_gtsam(np.linalg.inv(T), "sim3"))  # the truth: T_m_i
        out = gtsam.LevenbergMarquardtOptimizer(g, v).optimize()
        weights = [
            gtsam.noiseModel.mEstimator.DCS.Create(3 * len(lc.X_i)).weight(
                np.linalg.norm(f.unwhitenedError(out))
            )
            for f, lc in zip(fs, (good, bad))
        ]
        return _rot_err_deg(np.linalg.inv(to_matrix(out.atSimilarity3(S(1)))), T), weights

    err_plain, _ = solve(0.0)
    err_dcs, (w_good, w_bad) = solve(1.0)
    assert w_good > 0.9  # measured: 1.0
    assert w_bad < 0.2  # measured: 0.0002
    assert err_dcs < 0.3 * err_plain  # measured: 0.02 vs 1.95 deg


def _two_loop_rotation_error(phi: float, turn_deg: float) -> float:
    """Two loops of the same submaps from noisy point maps (depth noise 0.08 along the rays at ranges 2-5,
    0.02 across), the second turned ``turn_deg`` about its centre; the estimate starts at the truth.
    Returns the rotation error (deg) of the solution with the DCS kernel at ``phi`` x 3N (0: none)."""
    import gtsam
    from gtsam.symbol_shorthand import S

    from gsslam.factors import make_ray_point_factor, to_gtsam, to_matrix

    good, T = _ray_loop(np.random.default_rng(7), n=100, sigma_ray=0.08, sigma_perp=0.02)
    bad, _ = _ray_loop(np.random.default_rng(8), n=100, sigma_ray=0.08, sigma_perp=0.02)
    c = bad.X_i.mean(0)
    X_i = (bad.X_i - c) @ so3_exp(np.array([0.0, np.radians(turn_deg), 0.0])).T + c
    bad = dataclasses.replace(bad, X_i=X_i, T_i_m=umeyama(bad.X_m, X_i, with_scale=True))
    g = gtsam.NonlinearFactorGraph()
    g.add(gtsam.PriorFactorSimilarity3(S(0), gtsam.Similarity3(), gtsam.noiseModel.Isotropic.Sigma(7, 1e-6)))
    for lc in (good, bad):
        w = loop_weight(lc, "mono", dataclasses.replace(LoopConfig(), mono_dcs_phi=phi))
        g.add(make_ray_point_factor(S(1), S(0), lc.X_i, lc.X_m, w.sigma, w.sigma_perp, dcs_phi=w.dcs_phi))
    v = gtsam.Values()
    v.insert(S(0), gtsam.Similarity3())
    v.insert(S(1), to_gtsam(np.linalg.inv(T), "sim3"))
    out = gtsam.LevenbergMarquardtOptimizer(g, v).optimize()
    return _rot_err_deg(np.linalg.inv(to_matrix(out.atSimilarity3(S(1)))), T)


def test_narrower_dcs_resists_a_conflict_within_a_few_times_the_loops_noise():
    """Session 11: real mono loops conflict at chi2 / 3N of ~1-5 (several degrees wrong, their sigmas
    from their own residuals), where Phi = 3N (the default) keeps much of a wrong loop's weight. With
    noisy point maps and one loop turned 4 deg, ``loop.mono_dcs_phi=0.5`` leaves less of the turn in the
    solution than 1.0, and both far less than no kernel (on the real rows it is not better everywhere:
    docs/results.md, "Mono loops and the focal length, session 11")."""
    none, wide, narrow = (_two_loop_rotation_error(phi, 4.0) for phi in (0.0, 1.0, 0.5))
    assert none > 1.5  # measured: 1.92 deg (the two loops averaged)
    assert wide < 0.3 * none  # measured: 0.42 deg
    assert narrow < 0.8 * wide  # measured: 0.28 deg
