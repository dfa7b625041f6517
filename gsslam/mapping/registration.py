"""Registration of a keyframe against the map, with the information it carries (feedback to the graph).

SING3R's intra-submap refinement (photometric error under the alpha mask + scale-invariant depth)
finds the keyframe pose at which the frozen map explains the image best; here it is a robust
(Huber) Gauss-Newton over the pose's right perturbation, so that what the graph needs besides that
pose, how sure the registration is, comes with it: the Gauss-Newton information at the optimum,

    Lambda = c (J_c^T J_c / sigma_c^2 + J_d^T J_d / sigma_d^2)

with ``J`` the derivative of the colour residuals (alpha > 0.9) and of the median-normalised log
depth residuals (scale invariant) with respect to the pose's right perturbation (central differences
of renders, Huber-weighted), ``sigma`` each term's robust residual spread at the optimum and ``c``
(``registration_information_scale``) the discount for neighbouring pixels' correlated errors and for
the map having been fitted to nearby views. A registration is returned only where the render explains
the image (alpha coverage, photometric residual) and the information is well conditioned; a flat,
textureless render gives none. Its information is sent whole only where the Gauss-Newton converged (its
last step within that information's 1-sigma, :func:`gauss_newton`); elsewhere it is scaled by
``registration_unconverged_weight`` (0: not sent).

Only *converged* Gaussians are registered against (:mod:`gsslam.mapping.converged`, ``feedback_min_age``):
on a revisit the registration is a loop-like constraint against the map of the first pass. A frame whose
view is mostly explained by young Gaussians (share of the rendered weight from converged ones <
``feedback_min_converged``) gets no registration. See docs/mapping.md, "Registration feedback".
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np
import torch

from gsslam.mapping import exposure as X
from gsslam.mapping.converged import converged_mask, converged_share, converged_view
from gsslam.mapping.keyframes import Keyframe
from gsslam.mapping.pose import se3_delta_matrix
from gsslam.mapping.render_jacobian import subpixel_intrinsics, warp_jacobians
from gsslam.mapping.state import MapState, render

_log = logging.getLogger(__name__)

# Noise floors: a render that matches its image perfectly (a grey wall) must not claim a pose to the
# nanometre; colours are 8-bit and noisy (~0.02), depths of a point map no better than ~2 %.
SIGMA_COLOR_MIN = 0.02
SIGMA_LOG_DEPTH_MIN = 0.02


@dataclass(frozen=True)
class Registration:
    index: int
    T_world_cam: np.ndarray  # [4, 4] rigid, world units: the registered pose
    information: np.ndarray  # [6, 6] over the pose's right perturbation (phi, rho), world units
    coverage: float  # fraction of pixels with rendered alpha > 0.9
    residual: float  # robust spread of the colour residual at the optimum
    min_information: float  # smallest eigenvalue of the depth-normalised information
    condition: float  # its condition number
    converged: float = 1.0  # share of the rendered weight (alpha > 0.9) from converged Gaussians
    moved: bool = True  # Gauss-Newton took at least one step from the graph's pose
    at_minimum: bool = True  # its last step was within the information's 1-sigma (gauss_newton: converged)
    weight: float = 1.0  # share of the information sent: 1 at the minimum, else registration_unconverged_weight


def _render_at(state: MapState, kf: Keyframe, delta: torch.Tensor, intrinsics=None):
    """Render the map from ``kf``'s pose with ``delta`` (rho, phi) [6] as its refinement; kf is unchanged.
    ``intrinsics``: another camera at the mapper resolution (default: the mapper's)."""
    saved = kf.delta
    kf.delta = delta
    try:
        return render(state, kf.T_cam_world(state.device), intrinsics=intrinsics)
    finally:
        kf.delta = saved


def _masks(out, kf: Keyframe) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixels a render explains (alpha > 0.9) and those of them with a valid depth in both."""
    mask = out.alpha > 0.9
    return mask, mask & torch.isfinite(kf.depth) & (kf.depth > 1e-3) & (out.depth > 1e-3)


def _residuals_of(out, kf: Keyframe, mask: torch.Tensor, dmask: torch.Tensor):
    """Colour residuals [3M] of the render ``out`` under ``mask`` and median-normalised log-depth
    residuals [Md] under ``dmask``."""
    rc = (out.color - kf.image * out.alpha[..., None])[mask].reshape(-1)  # colour is premultiplied
    ld = torch.log(out.depth[dmask].clamp_min(1e-6)) - torch.log(kf.depth[dmask])
    return rc, ld - ld.median() if len(ld) else ld


def _residuals(state: MapState, kf: Keyframe, delta: torch.Tensor, mask: torch.Tensor, dmask: torch.Tensor):
    """:func:`_residuals_of` the render at ``delta``."""
    return _residuals_of(_render_at(state, kf, delta), kf, mask, dmask)


def _linearize(state: MapState, kf: Keyframe, delta: torch.Tensor):
    """Residuals, their Jacobians [., 6] over delta (rho, phi), robust sigmas: from the warp of one
    render (``registration_jacobian=warp``, :mod:`gsslam.mapping.render_jacobian`), the warp with the
    render's exact slopes from 2 more renders (``subpixel``) or by central differences of 12 more renders
    (``central``)."""
    out = _render_at(state, kf, delta)
    mask, dmask = _masks(out, kf)
    coverage = float(mask.float().mean())
    if int(mask.sum()) < 16:
        return None, coverage
    if state.cfg.registration_jacobian in ("warp", "subpixel"):
        shifted = None
        if state.cfg.registration_jacobian == "subpixel":  # the render's exact slopes: 2 more renders
            shifted = [_render_at(state, kf, delta, c) for c in subpixel_intrinsics(state.intrinsics)]
        rc, rd, Jc, Jd = _warp_terms(state, kf, out, mask, dmask, shifted)
    else:
        rc, rd, Jc, Jd = _central_terms(state, kf, delta, mask, dmask)
    terms = []
    for r, J, floor in ((rc, Jc, SIGMA_COLOR_MIN), (rd, Jd, SIGMA_LOG_DEPTH_MIN)):
        r = r.double().cpu().numpy()
        if len(r) < 16:
            continue
        sigma = max(1.4826 * float(np.median(np.abs(r))), floor)
        w = np.minimum(1.0, 1.345 * sigma / np.maximum(np.abs(r), 1e-12))  # Huber weights
        terms.append((r, J, w, sigma))
    return terms, coverage


def _warp_terms(state: MapState, kf: Keyframe, out, mask: torch.Tensor, dmask: torch.Tensor, shifted=None):
    """Residuals and their Jacobians [M, 6] from the render ``out`` (its warp; ``shifted``: the renders
    that give its exact slopes, :func:`~gsslam.mapping.render_jacobian.subpixel_intrinsics`)."""
    rc, rd = _residuals_of(out, kf, mask, dmask)
    Jc, Jd = warp_jacobians(out, kf.image, state.K, shifted=shifted)  # [H, W, 3, 6], [H, W, 6]
    Jc, Jd = Jc[mask].reshape(-1, 6), Jd[dmask]
    if len(rd) >= 16:  # the median moves with the pixels whose residual is at it: subtract their mean slope
        near = torch.argsort(rd.abs())[: max(16, len(rd) // 10)]
        Jd = Jd - Jd[near].mean(0)
    return rc, rd, Jc.double().cpu().numpy(), Jd.double().cpu().numpy()


def _central_terms(state: MapState, kf: Keyframe, delta: torch.Tensor, mask, dmask):
    """Residuals and their Jacobians [M, 6] by central differences of renders (12 renders)."""
    rc, rd = _residuals(state, kf, delta, mask, dmask)
    steps = [1e-3 * kf.median_depth] * 3 + [1e-3] * 3
    Jc, Jd = [], []
    for i, h in enumerate(steps):
        e = torch.zeros(6, device=delta.device)
        e[i] = h
        cp, dp = _residuals(state, kf, delta + e, mask, dmask)
        cm, dm = _residuals(state, kf, delta - e, mask, dmask)
        Jc.append(((cp - cm) / (2 * h)).double().cpu().numpy())
        Jd.append(((dp - dm) / (2 * h)).double().cpu().numpy())
    return rc, rd, np.stack(Jc, 1), np.stack(Jd, 1)


def _normal_equations(terms) -> tuple[np.ndarray, np.ndarray]:  # H [6, 6], g [6] over (rho, phi)
    H, g = np.zeros((6, 6)), np.zeros(6)
    for r, J, w, sigma in terms:
        H += (J * w[:, None]).T @ J / sigma**2
        g += (J * w[:, None]).T @ r / sigma**2
    return H, g


def _robust_cost(terms, sigmas) -> float:
    """Mean Huber cost per residual of each term under the given spreads, summed over the terms: the same
    spreads at both points of a step test, and a mean, so that neither the spread re-estimated at the
    new point nor the number of pixels under its alpha mask decides whether the step helped."""
    cost = 0.0
    for (r, *_), sigma in zip(terms, sigmas):
        a, k = np.abs(r) / sigma, 1.345
        cost += float(np.where(a <= k, a * a, 2 * k * a - k * k).mean())
    return cost


def _cost_at(state: MapState, kf: Keyframe, delta: torch.Tensor, sigmas) -> float:
    """The robust cost at ``delta`` from one render (its own alpha mask), under ``sigmas``."""
    out = _render_at(state, kf, delta)
    mask, dmask = _masks(out, kf)
    if int(mask.sum()) < 16:
        return float("inf")
    terms = [(r.double().cpu().numpy(),) for r in _residuals_of(out, kf, mask, dmask)[: len(sigmas)]]
    if any(len(t[0]) < 16 for t in terms):
        return float("inf")
    return _robust_cost(terms, sigmas)


@dataclass(frozen=True)
class GaussNewtonResult:
    information: np.ndarray  # [6, 6] (phi, rho) at the returned pose, x registration_information_scale
    coverage: float
    sigma: float  # colour residual spread there
    moved: bool  # at least one step was taken
    converged: bool  # the step still proposed there is within the information's own 1-sigma (below)
    step_mahalanobis: float  # that step's squared Mahalanobis distance under ``information``
    steps: int


@torch.no_grad()
def gauss_newton(state: MapState, kf: Keyframe, iterations: int) -> GaussNewtonResult:
    """Robust Gauss-Newton on ``kf.delta`` (left at the returned pose).

    A step is taken when it lowers the robust cost (:func:`_robust_cost`, the spreads of the point it
    starts from); otherwise it is halved, ``registration_step_halvings`` times at most (one render
    each), and the registration stops there. ``converged``: the Gauss-Newton step at the returned pose,
    measured by the information sent with it, is within one standard deviation (squared Mahalanobis
    distance < 1): the pose is where the map's evidence puts it, to the accuracy it claims (that last
    step is taken, so a converged registration always ends at the map's minimum). A pose whose
    next step is still larger (the cost test refused it: a non-convex or inconsistent view; or the
    iterations ran out) is not the map's minimum, and its information there describes the curvature at
    a point the map does not support (docs/mapping.md, "Registration feedback").
    """
    cfg = state.cfg
    scale = cfg.registration_information_scale
    delta = kf.delta.detach().clone()
    terms, coverage = _linearize(state, kf, delta)
    if not terms:
        return GaussNewtonResult(np.zeros((6, 6)), coverage, float("inf"), False, False, float("inf"), 0)
    moved, steps = False, 0
    while True:
        H, g = _normal_equations(terms)
        step = np.linalg.solve(H + 1e-6 * np.trace(H) / 6 * np.eye(6), -g)
        maha = scale * float(step @ H @ step)
        if maha < 1.0:  # the last Gauss-Newton step, within the noise: taken without a cost test
            delta = delta + torch.as_tensor(step, dtype=delta.dtype, device=delta.device)
            moved = True
            break
        if steps == iterations:
            break
        sigmas = [t[3] for t in terms]
        here = _robust_cost(terms, sigmas)
        taken = None
        for h in range(cfg.registration_step_halvings + 1):
            cand = delta + torch.as_tensor(step * 0.5**h, dtype=delta.dtype, device=delta.device)
            if _cost_at(state, kf, cand, sigmas) < here:
                taken = cand
                break
        if taken is None:
            break
        new_terms, new_coverage = _linearize(state, kf, taken)
        if not new_terms:
            break
        delta, terms, coverage, moved, steps = taken, new_terms, new_coverage, True, steps + 1
    kf.delta = delta
    P = np.r_[3, 4, 5, 0, 1, 2]  # (rho, phi) -> (phi, rho)
    return GaussNewtonResult(scale * H[np.ix_(P, P)], coverage, terms[0][3], moved, maha < 1.0, maha, steps)


def register(state: MapState, kf: Keyframe, iterations: int) -> Registration | None:
    """Register ``kf`` (not part of the map) against the map; None where the map cannot tell its pose.

    With an exposure on ``kf`` (the nearest keyframe's, :meth:`GaussianMapper.register`) the render is
    compared with the image brought back to the map's exposure (:func:`gsslam.mapping.exposure.unapply`).
    """
    cfg = state.cfg
    if kf.exposure is not None:
        kf = dataclasses.replace(kf, image=X.unapply(kf.image, kf.exposure), exposure=None)
    mask = converged_mask(state, cfg.feedback_min_age)
    coverage, share = converged_share(state, kf.T_cam_world(state.device), mask)
    if coverage < cfg.registration_min_coverage or share < cfg.feedback_min_converged:
        _log.debug("registration of %d: coverage %.2f, converged %.2f: too low", kf.index, coverage, share)
        return None
    gn = gauss_newton(converged_view(state, mask), kf, iterations)
    info, coverage, sigma = gn.information, gn.coverage, gn.sigma
    D = np.diag([1.0, 1.0, 1.0] + [kf.median_depth] * 3)  # translation in units of the depth
    ev = np.linalg.eigvalsh(D @ info @ D)
    cond = float(ev[-1] / max(ev[0], 1e-12))
    ok = (
        coverage >= cfg.registration_min_coverage
        and sigma <= cfg.registration_max_residual
        and ev[0] >= cfg.registration_min_information
        and cond <= cfg.registration_max_condition
    )
    _log.debug(
        "registration of %d: coverage %.2f converged %.2f sigma %.3f min info %.3g cond %.3g steps %d "
        "last step %.3g (%s)",
        kf.index,
        coverage,
        share,
        sigma,
        ev[0],
        cond,
        gn.steps,
        gn.step_mahalanobis,
        "kept" if ok else "gated",
    )
    if not ok:
        return None
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = kf.R, kf.t

    T = T @ se3_delta_matrix(kf.delta.detach().cpu().double()).numpy()
    weight = 1.0 if gn.converged else cfg.registration_unconverged_weight
    return Registration(
        kf.index, T, weight * info, coverage, sigma, float(ev[0]), cond, share, gn.moved, gn.converged, weight
    )
