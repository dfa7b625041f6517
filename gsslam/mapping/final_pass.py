"""The end-of-run global pass over all keyframes (poses fixed), with a few densification rounds."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np
import torch

from gsslam.mapping.keyframes import end_threads, torch_threads
from gsslam.mapping.levels import coarse_steps
from gsslam.mapping.rasterize_cpu import compositor_threads
from gsslam.mapping.state import MapState, refined_poses
from gsslam.mapping.window import adam_steps, run_stats

log = logging.getLogger(__name__)

_ERROR_STATE = ("err_sum", "err_count", "max_radius")


@contextmanager
def end_of_run_threads(cfg) -> Iterator[int]:
    """Threads of the work after the frames (this pass, the map's evaluation and panels); yields the
    compositor's count.

    Torch keeps ``num_threads`` (1): its thread pool synchronises around every small operation, and
    with 2 threads on a loaded 2-core machine a map step ran 18x slower (SSIM's convolutions 23-27x;
    docs/results.md, "Final pass threads, session 11"). The compositor's passes, milliseconds each,
    run on ``final_num_threads`` row bands (0: every core the process may use; nothing else of the run
    is busy then). Images are those of one band bit for bit; gradients differ by summation order.
    """
    threads = end_threads(cfg.final_num_threads)
    with torch_threads(cfg.num_threads), compositor_threads(threads):
        yield threads


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


def error_picker(state: MapState, order: list[int]):
    """A ``(pick(it), observe(it, idx, psnr))`` pair that spends the steps where the render errs most.

    The first shuffled epoch visits every keyframe once; afterwards a keyframe is drawn with
    probability proportional to its last measured mean squared error (``10^(-PSNR/10)`` of its latest
    step), so a keyframe twice as wrong gets twice the steps. Deterministic (the state's generator).
    """
    mse = {i: float("nan") for i in order}
    first = epoch_picker(state, order)
    seen = 0

    def pick(it: int) -> int:
        if seen < len(order):
            return first(it)
        w = np.array([mse[i] for i in order])
        w = np.where(np.isfinite(w), w, np.nanmax(w) if np.isfinite(w).any() else 1.0)
        return order[int(state.rng.choice(len(order), p=w / w.sum()))]

    def observe(it: int, idx: int, psnr_val: float) -> None:
        nonlocal seen
        seen += 1
        mse[idx] = 10.0 ** (-psnr_val / 10.0)

    return pick, observe


def final_iterations(cfg, n_keyframes: int, step_seconds: float = 0.0, run_seconds: float = 0.0) -> int:
    """Steps of the final pass: ``final_iterations_per_keyframe`` x keyframes, capped.

    Caps: ``final_max_iterations`` (steps; 0 none) and, when ``final_max_share`` > 0 and the run's
    seconds so far and the mean seconds per map step are known, the steps that keep the pass within that
    share of the whole run (``share / (1 - share)`` x the run so far).
    """
    iters = cfg.final_iterations_per_keyframe * n_keyframes
    if cfg.final_max_iterations > 0:
        iters = min(iters, cfg.final_max_iterations)
    share = cfg.final_max_share
    if 0.0 < share < 1.0 and step_seconds > 0 and run_seconds > 0:
        iters = min(iters, max(n_keyframes, int(share / (1.0 - share) * run_seconds / step_seconds)))
    return iters


def finalize(
    state: MapState,
    iterations: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    step_seconds: float = 0.0,
    run_seconds: float = 0.0,
) -> dict:
    """Global refinement at the end of a run: Adam over *all* keyframes (poses fixed).

    ``iterations`` defaults to :func:`final_iterations` (``final_iterations_per_keyframe`` x the
    keyframe count, capped by ``final_max_iterations`` and optionally by ``final_max_share`` of the run,
    so the pass stops growing with the length of the run). While every keyframe gets its
    ``final_iterations_per_keyframe`` steps they are visited in shuffled epochs; when a cap binds, after
    one epoch the steps go to the keyframes whose renders err most (:func:`error_picker`). Learning rates
    start at ``final_lr_scale`` x the configured ones and decay to 10 % of that over the pass; the flow
    loss is weighted by ``final_lambda_flow``. The first ``final_coarse_share`` of the steps render at half
    the mapper resolution (:mod:`gsslam.mapping.levels`). Afterwards only transparent Gaussians are pruned (no
    densification). ``progress(done, total)`` is called after every step. Returns stats.
    """
    cfg = state.cfg
    full = cfg.final_iterations_per_keyframe * len(state.order)
    if iterations is None:
        iters = final_iterations(cfg, len(state.order), step_seconds, run_seconds)
    else:
        iters = int(iterations)
    if not state.order or len(state.model) == 0 or iters <= 0:
        return {"iterations": 0, "num_gaussians": len(state.model)}
    order = list(state.order)
    capped = iters < full
    if capped:
        pick, watch = error_picker(state, order)
    else:
        pick, watch = epoch_picker(state, order), None  # every keyframe once per epoch, none left out
    visits = dict.fromkeys(order, 0)
    done = 0

    def observe(it: int, idx: int, psnr_val: float) -> None:
        nonlocal done
        done += 1
        visits[idx] += 1
        if watch is not None:
            watch(it, idx, psnr_val)
        if progress is not None:
            progress(done, iters)

    log.info(
        "final pass: %d steps over %d keyframes (%s), the compositor on %d thread(s)", iters, len(order),
        "capped: worst keyframes first" if capped else "shuffled epochs", end_threads(cfg.final_num_threads),
    )  # fmt: skip
    t0 = time.perf_counter()
    rounds = max(0, cfg.final_densify_rounds)
    bounds = np.linspace(0, iters, rounds + 2).round().astype(int)
    densified = 0
    first = last = None
    coarse = coarse_steps(cfg.final_coarse_share, iters)  # the pass's first steps, across its rounds
    with end_of_run_threads(cfg) as threads:
        reset_error_state(state)
        for r in range(rounds + 1):
            n = int(bounds[r + 1] - bounds[r])
            if n <= 0:
                continue
            lr0 = cfg.final_lr_scale * 0.1 ** (bounds[r] / max(1, iters - 1))
            f, last = adam_steps(
                state, n, pick, [], order, decay=0.1 ** (n / max(1, iters - 1)), lr_scale=lr0,
                lambda_flow=cfg.final_lambda_flow, observe=observe,
                coarse_steps=min(n, max(0, coarse - int(bounds[r]))),
            )  # fmt: skip
            first = f if first is None else first
            if r < rounds:  # densify where the whole map still errs; no error-based pruning
                state.model, state.densify_state, st = state.strategy.step(
                    state.model, state.densify_state, densify_only=True, generator=state.gen
                )
                densified += st["cloned"] + st["split"]
                reset_error_state(state)
    pruned = prune_transparent(state)
    counts = np.array(list(visits.values()))
    stats = run_stats(
        state, iters, t0, first, last, pruned=pruned, densified=densified, capped=capped, coarse=coarse,
        uncapped_iterations=full, visits_min=int(counts.min()), visits_max=int(counts.max()), threads=threads,
    )  # fmt: skip
    log.info("final pass done: %.1f s, step PSNR %.2f -> %.2f dB", stats.get("seconds", 0.0),
             first or 0.0, last or 0.0)  # fmt: skip
    return stats


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
    with end_of_run_threads(cfg):
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
