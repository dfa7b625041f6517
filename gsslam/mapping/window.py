"""The mapper's optimization step: Adam on the map (and selected keyframe poses) over keyframes.

Per step one keyframe is rendered and supervised by colour L1+SSIM, inverse-depth L1, depth-normal
consistency, the scale regularizer, the anchored pose loss (:mod:`gsslam.mapping.pose_refine`) for
keyframes with a free pose, and GaussianFlow's flow loss for stored keyframe pairs starting at it. The
per-Gaussian normalized error feeds the densification state (:mod:`gsslam.mapping.densify`).
:func:`optimize_window` is SING3R's sliding-window map optimization; :func:`adam_steps` is shared with
the final passes (:mod:`gsslam.mapping.final_pass`).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import torch

from gsslam.mapping import exposure as X
from gsslam.mapping import losses as L
from gsslam.mapping.adam import Adam
from gsslam.mapping.keyframes import Keyframe, torch_threads
from gsslam.mapping.levels import camera_matrix, coarse_intrinsics, coarse_keyframe
from gsslam.mapping.pose_refine import pose_loss
from gsslam.mapping.rasterize import RenderOutput
from gsslam.mapping.state import MapState, render


def optimize_window(state: MapState, iterations: int | None = None) -> dict:
    """Adam over the window's keyframes (plus revisits of older ones), then densify/prune; returns stats.

    Steps alternate between the newest keyframe and a random one of the window; a share
    ``revisit_fraction`` of the steps goes to a random keyframe older than the window instead, so
    regions seen earlier do not degrade. Only the newest ``pose_window`` keyframes (never the very
    first, the gauge) get joint pose refinement.
    """
    cfg, order, rng = state.cfg, state.order, state.rng
    iters = cfg.iterations if iterations is None else int(iterations)
    win = order[-cfg.window :]
    drop_spent_flows(state, win)
    if not win or len(state.model) == 0 or iters <= 0:
        return {"iterations": 0, "num_gaussians": len(state.model)}
    old = order[: -len(win)]
    pose_kfs = [i for i in win[-max(0, cfg.pose_window) :] if i != order[0]] if cfg.pose_refinement else []
    if cfg.pose_window <= 0:
        pose_kfs = []

    def pick(it: int) -> int:
        if old and rng.random() < cfg.revisit_fraction:
            return old[int(rng.integers(len(old)))]
        return win[-1] if it % 2 == 0 else win[int(rng.integers(len(win)))]

    n_new = sum(1 for i in win if state.steps.get(i, 0) == 0)  # not yet rendered: joined since the last call
    t0 = time.perf_counter()
    with torch_threads(cfg.num_threads):
        first, last = adam_steps(state, iters, pick, pose_kfs, win)
        active = torch.isin(state.model.keyframe_id, torch.tensor(win, device=state.device))
        state.model, state.densify_state, dstats = state.strategy.step(
            state.model, state.densify_state, active=active, generator=state.gen
        )
        extra = consolidate(state, int(round(cfg.consolidate_per_keyframe * n_new)))
    return run_stats(state, iters + extra, t0, first, last, consolidate_iterations=extra, **dstats)


def flows_read_at_end(cfg) -> bool:
    """Whether a pass over all keyframes reads the stored flows: the final pass and ``consolidate`` with
    ``final_lambda_flow`` > 0, or the joint refinement (``final_pose_iterations`` > 0) with
    ``lambda_flow`` > 0."""
    return cfg.final_lambda_flow > 0 or (cfg.final_pose_iterations > 0 and cfg.lambda_flow > 0)


def drop_spent_flows(state: MapState, win: list[int]) -> int:
    """Forget the stored flows no step can read any more; returns how many were dropped.

    A window step reads a flow ``(a, b)`` only while ``b`` is in the window (:func:`step_loss`), and the
    window is the newest keyframes of ``state.order``, which only grows: once ``b`` has left it, the flow
    is read again only by a pass over all keyframes that weighs flows (:func:`flows_read_at_end`). Without
    one the run keeps the flows of the window only (~0.17 MB per pair at 160x120) instead of every pair's;
    the results are the same (dict order of the kept flows is unchanged).
    """
    if flows_read_at_end(state.cfg):
        return 0
    live = set(win)
    spent = [ab for ab in state.flows if ab[1] not in live]
    for ab in spent:
        del state.flows[ab]
    return len(spent)


def consolidate(state: MapState, iterations: int) -> int:
    """The final pass spread over the run: ``iterations`` steps on keyframes older than the window.

    Each step goes to the older keyframe with the fewest map steps so far (ties in a random order), so
    every keyframe that left the window is visited in turn and the least trained first. Poses are fixed,
    learning rates are the configured ones x ``final_lr_scale`` x ``consolidate_lr_scale``; the steps
    render at the mapper resolution, or with ``consolidate_coarse`` at the coarse level
    (:mod:`gsslam.mapping.levels`), which blurs a map that gets no full steps afterwards. Off by default:
    it cost 0.3-0.8 dB at 640 px against the same steps in the final pass (docs/results.md, "Final pass
    share, session 7"). Returns the steps taken (0 without older keyframes).
    """
    cfg, order = state.cfg, state.order
    old = order[: -cfg.window] if len(order) > cfg.window else []
    if not old or iterations <= 0 or len(state.model) == 0:
        return 0
    tie = {i: float(r) for i, r in zip(old, state.rng.random(len(old)))}

    def pick(it: int) -> int:
        return min(old, key=lambda i: (state.steps.get(i, 0), tie[i]))

    coarse = iterations if cfg.consolidate_coarse else 0
    adam_steps(
        state, iterations, pick, [], order, lr_scale=cfg.final_lr_scale * cfg.consolidate_lr_scale,
        lambda_flow=cfg.final_lambda_flow, coarse_steps=coarse,
    )  # fmt: skip
    return iterations


def run_stats(state: MapState, iters: int, t0: float, first, last, **extra) -> dict:
    """The stats dict every optimisation pass returns (time since ``t0``, step PSNRs, map size)."""
    dt = time.perf_counter() - t0
    return {
        "iterations": iters,
        "seconds": dt,
        "ms_per_iteration": 1000 * dt / max(iters, 1),
        "psnr_first": first,
        "psnr_last": last,
        "num_gaussians": len(state.model),
        **extra,
    }


def adam_steps(
    state: MapState,
    iters: int,
    pick: Callable[[int], int],
    pose_kfs: list[int],
    win: list[int],
    decay: float = 1.0,
    lr_scale: float = 1.0,
    lr_pose: float | None = None,
    pose_prior_weight: float | None = None,
    lambda_flow: float | None = None,
    observe: Callable[[int, int, float], None] | None = None,
    coarse_steps: int = 0,
) -> tuple[float | None, float | None]:
    """``iters`` Adam steps on the keyframes ``pick(it)`` returns; returns (first, last) step PSNR.

    The map and the deltas of ``pose_kfs`` are optimized. Learning rates start at ``lr_scale`` x the
    configured ones (``lr_pose`` for the poses, default ``cfg.lr_pose`` unscaled) and fall
    exponentially to ``decay`` x their start over the steps. ``pose_prior_weight`` overrides
    ``lambda_pose_prior`` for the poses' anchor prior, ``lambda_flow`` the flow loss weight.
    ``observe(it, keyframe index, step PSNR)`` is called after every step (error tracking, progress).
    The first ``coarse_steps`` steps render at the coarse level (:mod:`gsslam.mapping.levels`).
    """
    cfg, kfs = state.cfg, state.keyframes
    params = {k: v.detach().clone().requires_grad_(True) for k, v in state.model.params().items()}
    for k, v in params.items():
        setattr(state.model, k, v)
    lrs = {
        "means": cfg.lr_means,
        "quats": cfg.lr_quats,
        "log_scales": cfg.lr_scales,
        "opacity_logits": cfg.lr_opacity,
        "sh_dc": cfg.lr_colors,
    }
    groups = [{"params": [params[k]], "lr": lr_scale * lrs[k]} for k in params]
    for i in pose_kfs:
        kfs[i].delta = kfs[i].delta.detach().clone().requires_grad_(True)
    if pose_kfs:
        groups.append({"params": [kfs[i].delta for i in pose_kfs], "lr": lr_pose or cfg.lr_pose})
    exposed = exposure_keyframes(state)
    for i in exposed:
        e = kfs[i].exposure
        kfs[i].exposure = (X.identity(state.device) if e is None else e.detach().clone()).requires_grad_(True)
    if exposed:
        groups.append({"params": [kfs[i].exposure for i in exposed], "lr": lr_scale * cfg.lr_exposure})
    opt = Adam(groups, eps=1e-15)  # torch.optim.Adam's arithmetic, without importing torch._dynamo
    base = [g["lr"] for g in opt.param_groups]
    gamma = decay ** (1.0 / max(1, iters - 1))
    first = last = None
    for it in range(iters):
        idx = pick(it)
        loss, psnr_val = step_loss(
            state, kfs[idx], idx in pose_kfs, win, pose_prior_weight, lambda_flow, coarse=it < coarse_steps
        )
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if decay != 1.0:
            for g, lr0 in zip(opt.param_groups, base):
                g["lr"] = lr0 * gamma ** (it + 1)
        state.steps[idx] = state.steps.get(idx, 0) + 1
        first = psnr_val if first is None else first
        last = psnr_val
        if observe is not None:
            observe(it, idx, psnr_val)
    for i in pose_kfs:
        kfs[i].delta = kfs[i].delta.detach()
    for i in exposed:
        kfs[i].exposure = kfs[i].exposure.detach()
    state.model = state.model.detached()
    return first, last


def exposure_keyframes(state: MapState) -> list[int]:
    """The keyframes whose exposure the steps optimise: all but the first (the gauge), when enabled."""
    return list(state.order[1:]) if state.cfg.exposure else []


def step_loss(
    state: MapState,
    kf: Keyframe,
    pose: bool,
    win: list[int],
    pose_prior_weight: float | None = None,
    lambda_flow: float | None = None,
    coarse: bool = False,
) -> tuple[torch.Tensor, float]:
    """The loss of one step at keyframe ``kf`` and its PSNR; updates the densification state.

    ``lambda_flow`` overrides ``cfg.lambda_flow`` (the final pass uses ``final_lambda_flow``).
    ``coarse``: render at the coarse level against the keyframe reduced to it
    (:mod:`gsslam.mapping.levels`); such a step has no flow term (flows live at the mapper resolution)
    and leaves the densification state alone (its errors and radii are those of the mapper resolution).
    """
    cfg, m, dev = state.cfg, state.model, state.device
    w_flow = cfg.lambda_flow if lambda_flow is None else lambda_flow
    intr, K = None, state.K
    if coarse:
        intr = coarse_intrinsics(state.intrinsics)
        K = camera_matrix(intr, state.K)
        kf = coarse_keyframe(kf, intr.width, intr.height)
        w_flow = 0.0
    out = render(state, kf.T_cam_world(dev, with_delta=True), intrinsics=intr)
    # [h, w, 3] the render through the keyframe's exposure; the exposure's own fit on covered pixels
    color, fit = X.exposed(out.color, out.alpha, kf.exposure, kf.image)
    loss = L.color_loss(color, kf.image, cfg.lambda_ssim)
    if fit is not None:
        loss = loss + fit + cfg.lambda_exposure * X.regularizer(kf.exposure)
    unit = kf.median_depth if cfg.depth_scale_free else 1.0
    loss = loss + cfg.lambda_depth * L.inverse_depth_l1(
        out.depth, kf.depth, weight=kf.depth_weight, unit=unit
    )
    if cfg.lambda_depth_normal > 0:
        loss = loss + cfg.lambda_depth_normal * L.depth_normal_consistency(
            out.depth, out.normal, K, mask=out.alpha.detach() > 0.5
        )
    loss = loss + cfg.lambda_scale * L.scale_regularizer(m.log_scales)
    if pose:
        loss = loss + pose_loss(cfg, out, kf, prior_weight=pose_prior_weight)
    # GaussianFlow: projected motion of the Gaussians vs measured flow, for pairs starting here
    err = None
    vis = None if coarse else visible(out)  # [N] bool, once per step (flow weights, error, radii)
    for (a, b), (flow, valid) in state.flows.items():
        if a != kf.index or b not in win or w_flow <= 0:
            continue
        kb = state.keyframes[b]
        uv_b = project(state.K, m.means, kb.T_cam_world(dev, with_delta=b in win and kb.delta.requires_grad))
        fl, e, _ = L.flow_loss(
            out.means2d,
            uv_b,
            flow,
            valid,
            weight=vis.float(),
            sigma=cfg.flow_sigma_px,
            inlier_prior=cfg.flow_inlier_prior,
            outlier_range=cfg.flow_outlier_range_px,
        )
        loss = loss + w_flow * fl
        err = e if err is None else torch.where(torch.isfinite(e), e, err)
    if coarse:
        return loss, float(L.psnr(color.detach().clamp(0, 1), kf.image))
    with torch.no_grad():
        if err is None:  # photometric analogue of the normalized error, at the Gaussians' pixels
            diff = (color - kf.image).abs().mean(-1) / (kf.image.mean(-1) + 0.1)
            e = L.sample_image(diff[..., None], out.means2d.detach())[:, 0]
            err = torch.where(vis, e, torch.full_like(e, float("nan")))
        radius = torch.where(vis, out.radii.float(), torch.zeros_like(err))
        state.strategy.update_state(state.densify_state, err, radius)
        psnr_val = float(L.psnr(color.detach().clamp(0, 1), kf.image))
    return loss, psnr_val


def project(
    K: torch.Tensor,  # [3, 3]
    means: torch.Tensor,  # [N, 3] world
    T_cam_world: torch.Tensor,  # [4, 4]
) -> torch.Tensor:  # [N, 2] pixels
    p = means @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    z = p[:, 2].clamp_min(1e-3)
    return torch.stack([K[0, 0] * p[:, 0] / z + K[0, 2], K[1, 1] * p[:, 1] / z + K[1, 2]], -1)


@torch.no_grad()
def visible(out: RenderOutput) -> torch.Tensor:
    """Gaussians drawn in this view and not hidden behind the rendered surface -> [N] bool."""
    d = L.sample_image(out.depth.detach()[..., None], out.means2d.detach())[:, 0]
    return (out.radii > 0) & (out.depths.detach() <= 1.1 * d + 1e-3)
