"""The end-of-run global pass over all keyframes (poses fixed), with a few densification rounds."""

from __future__ import annotations

import time

import numpy as np
import torch

from gsslam.mapping.keyframes import torch_threads
from gsslam.mapping.state import MapState, refined_poses
from gsslam.mapping.window import adam_steps, run_stats

_ERROR_STATE = ("err_sum", "err_count", "max_radius")


def epoch_picker(state: MapState, order: list[int]):
    """A ``pick(it)`` that visits every keyframe of ``order`` once per shuffled epoch."""
    queue: list[int] = []

    def pick(it: int) -> int:
        if not queue:
            queue.extend(order[int(j)] for j in state.rng.permutation(len(order)))
        return queue.pop()

    return pick


def reset_error_state(state: MapState) -> None:
    """Errors from the run so far describe a map that no longer exists: start counting afresh."""
    for k in _ERROR_STATE:
        state.densify_state[k] = torch.zeros_like(state.densify_state[k])


def prune_transparent(state: MapState) -> int:
    """Drop Gaussians with opacity below ``min_opacity``; returns how many."""
    keep = state.model.opacities >= state.cfg.min_opacity
    state.model = state.model.select(keep)
    state.densify_state = {k: v[keep] for k, v in state.densify_state.items()}
    return int((~keep).sum())


def finalize(state: MapState, iterations: int | None = None) -> dict:
    """Global refinement at the end of a run: Adam over *all* keyframes (random order, poses fixed).

    ``iterations`` defaults to ``final_iterations_per_keyframe`` x the keyframe count (so the
    pass costs the same per keyframe on short and long runs). Learning rates start at ``final_lr_scale`` x the
    configured ones and decay to 10 % of that over the pass; the flow loss is weighted by
    ``final_lambda_flow``. Afterwards only transparent Gaussians are pruned (no densification).
    Returns stats.
    """
    cfg = state.cfg
    if iterations is None:
        iters = cfg.final_iterations_per_keyframe * len(state.order)
    else:
        iters = int(iterations)
    if not state.order or len(state.model) == 0 or iters <= 0:
        return {"iterations": 0, "num_gaussians": len(state.model)}
    order = list(state.order)
    pick = epoch_picker(state, order)  # every keyframe once per epoch, so none is left out
    t0 = time.perf_counter()
    rounds = max(0, cfg.final_densify_rounds)
    bounds = np.linspace(0, iters, rounds + 2).round().astype(int)
    densified = 0
    first = last = None
    with torch_threads(cfg.num_threads):
        reset_error_state(state)
        for r in range(rounds + 1):
            n = int(bounds[r + 1] - bounds[r])
            if n <= 0:
                continue
            lr0 = cfg.final_lr_scale * 0.1 ** (bounds[r] / max(1, iters - 1))
            f, last = adam_steps(
                state, n, pick, [], order, decay=0.1 ** (n / max(1, iters - 1)), lr_scale=lr0,
                lambda_flow=cfg.final_lambda_flow,
            )  # fmt: skip
            first = f if first is None else first
            if r < rounds:  # densify where the whole map still errs; no error-based pruning
                state.model, state.densify_state, st = state.strategy.step(
                    state.model, state.densify_state, densify_only=True, generator=state.gen
                )
                densified += st["cloned"] + st["split"]
                reset_error_state(state)
    pruned = prune_transparent(state)
    return run_stats(state, iters, t0, first, last, pruned=pruned, densified=densified)


def refine_joint(state: MapState, iterations: int | None = None) -> dict:
    """Final joint refinement: keyframe poses (se(3) deltas, the first keyframe fixed) and map together.

    Runs after :func:`finalize` (and the graph's batch refinement): every keyframe once per shuffled
    epoch, the step loss of :func:`gsslam.mapping.window.step_loss` (colour L1+SSIM, inverse depth,
    depth-normal, flow) plus the anchored pose loss for every free keyframe. Map learning rates start at
    10 % (the map is already converged) and poses at ``final_lr_pose``, both decaying to 10 %. Returns
    stats including the mean / max keyframe translation moved (world units).
    """
    cfg = state.cfg
    iters = cfg.final_pose_iterations if iterations is None else int(iterations)
    if len(state.order) < 2 or len(state.model) == 0 or iters <= 0:
        return {"iterations": 0, "num_gaussians": len(state.model)}
    order = list(state.order)
    free = order[1:]  # the first keyframe is the gauge
    before = refined_poses(state)
    pick = epoch_picker(state, order)
    t0 = time.perf_counter()
    with torch_threads(cfg.num_threads):
        reset_error_state(state)
        first, last = adam_steps(
            state, iters, pick, free, order, decay=0.1, lr_scale=0.1,
            lr_pose=cfg.final_lr_pose, pose_prior_weight=cfg.final_pose_prior,
        )  # fmt: skip
        pruned = prune_transparent(state)
    after = refined_poses(state)
    moved = [float(np.linalg.norm(after[i][:3, 3] - before[i][:3, 3])) for i in order]
    return run_stats(
        state, iters, t0, first, last, pruned=pruned,
        pose_moved_mean=float(np.mean(moved)), pose_moved_max=float(np.max(moved)),
    )  # fmt: skip
