"""ATE and RPE by invariance: a trajectory moved by a random Sim(3)/SE(3) and aligned back has ~0 error."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import perturb, random_sim3, transform_trajectory

from gsslam.eval.align import AlignmentError, align_positions
from gsslam.eval.ate import compute_ate
from gsslam.eval.report import evaluate
from gsslam.eval.rpe import RpeError, compute_rpe
from gsslam.geometry import make_T, so3_exp
from gsslam.io.trajectory import read_tum
from gsslam.types import Trajectory


@pytest.fixture(scope="module")
def teddy(bundled_tum) -> Trajectory:
    return read_tum(bundled_tum / "groundtruth.txt")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sim3_alignment_removes_a_random_similarity(teddy, seed):
    rng = np.random.default_rng(seed)
    scale = float(np.exp(rng.uniform(-2, 2)))
    S = random_sim3(rng, scale)
    est = Trajectory(teddy.timestamps, transform_trajectory(S, teddy.poses))
    rep = evaluate(teddy, est, align="sim3")
    assert rep.ate.stats.rmse < 1e-9
    assert rep.ate.stats.max < 1e-9
    assert rep.ate.alignment.scale == pytest.approx(1.0 / scale, rel=1e-9)
    # The alignment is the inverse of S.
    np.testing.assert_allclose(rep.ate.alignment.matrix @ S, np.eye(4), atol=1e-8)
    assert rep.rpe.translation.max < 1e-9
    assert rep.rpe.rotation_deg.max < 1e-5


def test_se3_alignment_removes_rigid_motion_but_not_scale(teddy, rng):
    est = Trajectory(teddy.timestamps, transform_trajectory(random_sim3(rng, 1.0), teddy.poses))
    assert evaluate(teddy, est, align="se3").ate.stats.rmse < 1e-9
    assert evaluate(teddy, est, align="none").ate.stats.rmse > 0.1  # the motion itself is an error
    scaled = Trajectory(teddy.timestamps, transform_trajectory(random_sim3(rng, 0.5), teddy.poses))
    se3 = evaluate(teddy, scaled, align="se3")
    sim3 = evaluate(teddy, scaled, align="sim3")
    assert se3.ate.alignment.scale == 1.0
    assert se3.ate.stats.rmse > 0.05  # half of a ~1 m path cannot be explained by a rigid motion
    assert sim3.ate.stats.rmse < 1e-9
    # RPE after SE(3) alignment sees the halved steps; after Sim(3) it does not.
    assert se3.rpe.translation.mean > 0.3 * np.mean(np.linalg.norm(np.diff(teddy.positions, axis=0), axis=1))
    assert sim3.rpe.translation.max < 1e-9


def test_known_offset_gives_exact_ate_without_alignment(teddy):
    poses = teddy.poses.copy()
    poses[:, :3, 3] += [0.03, -0.04, 0.0]  # every position 5 cm off
    rep = evaluate(teddy, Trajectory(teddy.timestamps, poses), align="none")
    for k in ("rmse", "mean", "median", "min", "max"):
        assert getattr(rep.ate.stats, k) == pytest.approx(0.05, abs=1e-12)
    assert rep.ate.stats.std == pytest.approx(0.0, abs=1e-12)
    assert rep.rpe.translation.max < 1e-12  # a constant world offset changes no relative pose


def test_rpe_known_rotation_error():
    # gt: straight line; est: same but each relative step also rotates by 2 deg about z.
    n = 6
    gt = np.stack([make_T(np.eye(3), [i, 0, 0]) for i in range(n)])
    R = so3_exp(np.radians([0, 0, 2.0]))
    est = [np.eye(4)]
    for _ in range(n - 1):
        est.append(est[-1] @ make_T(R, [1, 0, 0]))
    res = compute_rpe(gt, np.stack(est), delta=1)
    np.testing.assert_allclose(res.rotation_errors_deg, 2.0, atol=1e-10)
    np.testing.assert_allclose(res.translation_errors, 0.0, atol=1e-12)  # E = (I,1)^-1 (R,1): t(E)=0
    res2 = compute_rpe(gt, np.stack(est), delta=2)  # pairs (0,2), (2,4): each rotates by 4 deg
    assert res2.rotation_deg.n == 2
    np.testing.assert_allclose(res2.rotation_errors_deg, 4.0, atol=1e-10)


def test_metrics_do_not_modify_inputs(teddy, rng):
    est = perturb(teddy, rng, scale=2.0, every=2)
    g_t, g_p, e_t, e_p = teddy.timestamps.copy(), teddy.poses.copy(), est.timestamps.copy(), est.poses.copy()
    for align in ("sim3", "se3", "none"):
        evaluate(teddy, est, align=align, rpe_delta=3)
    np.testing.assert_array_equal(teddy.timestamps, g_t)
    np.testing.assert_array_equal(teddy.poses, g_p)
    np.testing.assert_array_equal(est.timestamps, e_t)
    np.testing.assert_array_equal(est.poses, e_p)


def test_noise_level_is_recovered(teddy, rng):
    est = perturb(teddy, rng, scale=3.0, trans_noise=0.01, rot_noise=0.0, time_jitter=0.0)
    ate, assoc = compute_ate(teddy, est, "sim3")
    assert len(assoc) == len(teddy)
    # 3 sigma_xyz^2 = E|n|^2: rmse of isotropic 1 cm noise is ~1.73 cm (in the estimate's units / 3).
    assert ate.stats.rmse == pytest.approx(np.sqrt(3) * 0.01 / 3.0, rel=0.15)


def test_alignment_errors():
    pts = np.random.default_rng(0).normal(size=(2, 3))
    with pytest.raises(AlignmentError, match="at least 3"):
        align_positions(pts, pts, "sim3")
    line = np.outer(np.arange(5.0), [1.0, 2.0, 3.0])
    with pytest.raises(AlignmentError, match="collinear"):
        align_positions(line, line, "se3")
    with pytest.raises(AlignmentError, match="unknown alignment"):
        align_positions(pts, pts, "affine")
    assert align_positions(pts, pts, "none").scale == 1.0  # no alignment needs no minimum


def test_rpe_errors():
    I = np.tile(np.eye(4), (3, 1, 1))
    with pytest.raises(RpeError, match="at least 4"):
        compute_rpe(I, I, delta=3)
    with pytest.raises(RpeError, match="positive integer"):
        compute_rpe(I, I, delta=0)
