"""Per-submap translation stretch (mono): factors whose keyframe translations scale by ``exp(sigma)``.

A mono submap's encoder gives its keyframes rigid local poses ``L_j = [R_j, t_j]`` and point maps in the
submap's own units; the submap's Sim(3) variable ``S`` scales both together. The *stretch* ``sigma``
(a 1-D ``Vector`` variable, a log factor) scales the local translations alone::

    L_j(sigma) = [R_j, exp(sigma) t_j]          a point p seen by keyframe j: R_j p + exp(sigma) t_j

so a factor can move a submap's translations without moving its depth. The factors here are the submap
graph's factors that read local keyframe translations, with the stretch of each submap involved as an
extra variable (their residuals are those of :mod:`factors.flow`, :mod:`factors.points` and
:mod:`factors.submap_alignment` at the stretched local poses):

- ``make_stretched_flow_factor(a, b, ta, tb, ...)``: ``L_a``, ``L_b`` stretched by ``ta``, ``tb``;
- ``make_stretched_point_factor(a, b, ta, P_a, o_a, X_b, sigma)``: ``X_a = P_a + exp(ta) o_a``
  (adjacency: ``P_a = R_Z X``, ``o_a = t_Z``, the shared frame's camera in submap a);
- ``make_stretched_alignment_factor(a, b, ta, Z, ...)``: ``t_Z`` stretched by ``ta``;
- ``make_stretched_ray_point_factor(a, b, ta, tb, P_a, o_a, P_b, o_b, ...)``: mono loop points
  (:mod:`factors.loop_rays`), ``X = P + exp(t) o`` with ``o`` the local translation of the keyframe
  that saw each point; the rays ``u_k`` (and so ``W_k``) are fixed at the unstretched points;
- ``make_stretch_prior_factor(t, sigma)``: ``r = sigma_t / sigma`` (prior mean 0).

Jacobian in ``sigma`` (exact, no chart: the variable is a vector): a right translation perturbation
``u`` of ``S`` moves every local point ``x -> x + u`` (``S Exp(u) x = S (x + u)`` to first order), and a
camera read through ``L^-1`` sees the same move as ``t -> t + u``; so for the rows of a point whose
local offset is ``exp(sigma) o``: ``d r / d sigma = J_u exp(sigma) o`` with ``J_u`` the factor's
Jacobian in that variable's translation columns (3:6). Tested against numerical derivatives.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ._lie import check_group, check_positive, check_shape, fill, pose_sigmas, read_transform
from .errors import FactorInputError
from .flow import flow_residual, mixture_weights
from .loop_rays import make_ray_point_factor, ray_point_residual, ray_whitening
from .points import checked_point_pair, point_residual
from .submap_alignment import alignment_residual

_GROUP = "sim3"


def read_stretch(values: gtsam.Values, key: int) -> float:
    """The log-stretch of a submap (a 1-D Vector value)."""
    return float(values.atVector(key)[0])


def stretched(L: np.ndarray, sigma: float) -> np.ndarray:  # L [..., 4, 4] rigid -> [..., 4, 4]
    """Local pose(s) with the translation multiplied by ``exp(sigma)``."""
    out = np.array(L, dtype=np.float64, copy=True)
    out[..., :3, 3] *= np.exp(sigma)
    return out


def make_stretch_prior_factor(key: int, sigma: float) -> gtsam.NonlinearFactor:
    """Prior ``sigma_t ~ 0`` with std ``sigma`` on a stretch variable."""
    noise = gtsam.noiseModel.Isotropic.Sigma(1, check_positive("sigma", sigma))
    return gtsam.PriorFactorVector(int(key), np.zeros(1), noise)


def _distinct(*keys: int) -> None:
    if len(set(int(k) for k in keys)) != len(keys):
        raise FactorInputError("a stretched factor needs distinct keys (two submaps and their stretches)")


def make_stretched_flow_factor(
    key_a: int,
    key_b: int,
    key_ta: int,
    key_tb: int,
    uv_src: np.ndarray,  # [N, 2] pixels in frame a
    depth_src: np.ndarray,  # [N] z in frame a (units of submap a)
    uv_tgt: np.ndarray,  # [N, 2] pixels in frame b
    K: np.ndarray,  # [3, 3]
    sigma_px: float = 1.0,
    weight: np.ndarray | None = None,  # [N] a-priori weights in [0, 1]
    inlier_prior: float = 0.9,
    outlier_range_px: float = 50.0,
    L_a: np.ndarray | None = None,  # [4, 4] rigid local pose of camera a in submap a (unstretched)
    L_b: np.ndarray | None = None,  # [4, 4] rigid local pose of camera b in submap b (unstretched)
    robust: bool = True,
    group: str = _GROUP,
) -> gtsam.CustomFactor:
    """The flow factor of :mod:`factors.flow` (Sim(3) submaps) with ``L_a``, ``L_b`` stretched; 2N rows."""
    check_group(group)
    from .flow import make_flow_factor  # validates the inputs exactly as the plain factor does

    make_flow_factor(key_a, key_b, uv_src, depth_src, uv_tgt, K, sigma_px, weight, inlier_prior,
                     outlier_range_px, group, L_a, L_b, robust)  # fmt: skip
    _distinct(key_a, key_b, key_ta, key_tb)
    uv_src, uv_tgt, d, K = (np.asarray(x, dtype=np.float64) for x in (uv_src, uv_tgt, depth_src, K))
    N = len(uv_src)
    c = np.ones(N) if weight is None else np.asarray(weight, dtype=np.float64)
    La = np.eye(4) if L_a is None else np.asarray(L_a, dtype=np.float64)
    Lb = np.eye(4) if L_b is None else np.asarray(L_b, dtype=np.float64)
    x = (uv_src[:, 0] - K[0, 2]) / K[0, 0]
    y = (uv_src[:, 1] - K[1, 2]) / K[1, 1]
    P_a = np.stack([x * d, y * d, d], axis=1) @ La[:3, :3].T  # [N, 3] rotated, offset added per call
    sqrt_c = np.sqrt(c) / sigma_px

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        ka, kb, kta, ktb = this.keys()
        o_a = np.exp(read_stretch(values, kta)) * La[:3, 3]
        o_b = np.exp(read_stretch(values, ktb)) * Lb[:3, 3]
        Lb_inv = np.eye(4)
        Lb_inv[:3, :3] = Lb[:3, :3].T
        Lb_inv[:3, 3] = -Lb[:3, :3].T @ o_b
        e, JA, JB, valid = flow_residual(
            read_transform(values, ka, group), read_transform(values, kb, group),
            P_a + o_a, Lb_inv, K, uv_tgt, group, H is not None,
        )  # fmt: skip
        s = (
            sqrt_c * np.sqrt(mixture_weights(e, sigma_px, inlier_prior, outlier_range_px))
            if robust
            else sqrt_c
        )
        s = np.where(valid, s, 0.0)
        if H is not None:
            dim = JA.shape[2]
            JA, JB = JA * s[:, None, None], JB * s[:, None, None]
            H[0] = JA.reshape(-1, dim)
            H[1] = JB.reshape(-1, dim)
            H[2] = (JA[:, :, 3:6] @ o_a).reshape(-1, 1)
            H[3] = (JB[:, :, 3:6] @ o_b).reshape(-1, 1)
        return (e * s[:, None]).ravel()

    noise = gtsam.noiseModel.Unit.Create(2 * N)
    return gtsam.CustomFactor(noise, [key_a, key_b, key_ta, key_tb], error)


def make_stretched_point_factor(
    key_a: int,
    key_b: int,
    key_ta: int,
    P_a: np.ndarray,  # [N, 3] submap-a local points without their keyframe offset
    o_a: np.ndarray,  # [3] or [N, 3] the (unstretched) local translation of the keyframe that saw them
    X_b: np.ndarray,  # [N, 3] in submap b's local frame (unstretched: b's frame-0 points)
    sigma: float | np.ndarray,  # scalar or [N], world units
    group: str = _GROUP,
) -> gtsam.CustomFactor:
    """Point coincidence ``S_a(P_a + exp(t_a) o_a) ~ S_b(X_b)`` (:mod:`factors.points`); 3N rows."""
    check_group(group)
    P_a, X_b, w = checked_point_pair("stretched point factor", key_a, key_b, P_a, X_b, sigma)
    o = np.broadcast_to(check_shape("o_a", np.atleast_2d(o_a), (None, 3)), P_a.shape).copy()
    _distinct(key_a, key_b, key_ta)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        ka, kb, kta = this.keys()
        oa = np.exp(read_stretch(values, kta)) * o
        r, JA, JB = point_residual(
            read_transform(values, ka, group), read_transform(values, kb, group), P_a + oa, X_b, w, group,
            H is not None,
        )  # fmt: skip
        if H is not None:
            JA3 = JA.reshape(len(P_a), 3, -1)[:, :, 3:6]  # d r_k / d u = d r_k / d X_a[k]
            H[2] = np.einsum("nij,nj->ni", JA3, oa).reshape(-1, 1)
        fill(H, 0, JA)
        fill(H, 1, JB)
        return r

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3 * len(P_a)), [key_a, key_b, key_ta], error)


def make_stretched_alignment_factor(
    key_a: int,
    key_b: int,
    key_ta: int,
    T_a_b: np.ndarray,  # [4, 4] rigid, unstretched: the shared frame's local pose in submap a
    rot_sigma: float,
    trans_sigma: float,
    group: str = _GROUP,
) -> gtsam.CustomFactor:
    """Submap alignment (:mod:`factors.submap_alignment`) with ``t_Z`` stretched by ``key_ta``; 6 rows."""
    check_group(group)
    Z = check_shape("T_a_b", T_a_b, (4, 4))
    if not np.allclose(Z[:3, :3] @ Z[:3, :3].T, np.eye(3), atol=1e-5) or not np.allclose(Z[3], [0, 0, 0, 1]):
        raise FactorInputError("T_a_b must be a rigid 4x4 transform (orthonormal rotation, last row 0 0 0 1)")
    _distinct(key_a, key_b, key_ta)
    noise = gtsam.noiseModel.Diagonal.Sigmas(pose_sigmas(rot_sigma, trans_sigma))

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        ka, kb, kta = this.keys()
        Zs = stretched(Z, read_stretch(values, kta))
        r, JA, JB = alignment_residual(
            read_transform(values, ka, group), read_transform(values, kb, group), Zs, group, H is not None
        )
        if H is not None:
            H[2] = (JA[:, 3:6] @ Zs[:3, 3]).reshape(-1, 1)
        fill(H, 0, JA)
        fill(H, 1, JB)
        return r

    return gtsam.CustomFactor(noise, [key_a, key_b, key_ta], error)


def make_stretched_ray_point_factor(
    key_a: int,
    key_b: int,
    key_ta: int,
    key_tb: int,
    P_a: np.ndarray,  # [N, 3] submap-a local points less their keyframe's translation
    o_a: np.ndarray,  # [N, 3] that (unstretched) translation
    P_b: np.ndarray,  # [N, 3] the same for submap b
    o_b: np.ndarray,  # [N, 3]
    sigma_ray: float | np.ndarray,
    sigma_perp: float | np.ndarray,
    dcs_phi: float = 0.0,
) -> gtsam.CustomFactor:
    """The ray-point loop factor (:mod:`factors.loop_rays`) with both submaps' points stretched; 3N rows."""
    o_a, o_b = check_shape("o_a", o_a, (None, 3)), check_shape("o_b", o_b, (len(o_a), 3))
    X_a, X_b = np.asarray(P_a, dtype=np.float64) + o_a, np.asarray(P_b, dtype=np.float64) + o_b
    plain = make_ray_point_factor(key_a, key_b, X_a, X_b, sigma_ray, sigma_perp, dcs_phi)  # validates
    _distinct(key_a, key_b, key_ta, key_tb)
    n = len(X_a)
    sr = np.broadcast_to(np.asarray(sigma_ray, dtype=np.float64), (n,))
    sp = np.broadcast_to(np.asarray(sigma_perp, dtype=np.float64), (n,))
    W = ray_whitening(X_a, sr, sp)  # rays fixed at the unstretched points
    P_a, P_b = X_a - o_a, X_b - o_b

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        ka, kb, kta, ktb = this.keys()
        oa, ob = np.exp(read_stretch(values, kta)) * o_a, np.exp(read_stretch(values, ktb)) * o_b
        r, JA, JB = ray_point_residual(
            read_transform(values, ka, _GROUP), read_transform(values, kb, _GROUP), P_a + oa, P_b + ob, W,
            H is not None,
        )  # fmt: skip
        if H is not None:
            H[0], H[1] = JA, JB
            H[2] = np.einsum("nij,nj->ni", JA.reshape(n, 3, 7)[:, :, 3:6], oa).reshape(-1, 1)
            H[3] = np.einsum("nij,nj->ni", JB.reshape(n, 3, 7)[:, :, 3:6], ob).reshape(-1, 1)
        return r

    return gtsam.CustomFactor(plain.noiseModel(), [key_a, key_b, key_ta, key_tb], error)


__all__ = [
    "make_stretch_prior_factor",
    "make_stretched_ray_point_factor",
    "make_stretched_alignment_factor",
    "make_stretched_flow_factor",
    "make_stretched_point_factor",
    "read_stretch",
    "stretched",
]
