"""The end-of-run batch solve, one-shot or staged (docs/graph.md, "The final batch").

The graph's objective has local minima: the flow factors weigh every correspondence by its posterior
inlier probability (a redescending cost) and the RGB-D ICP factors sit under a Huber kernel, so a
Levenberg-Marquardt run from the incremental estimate stays in whatever basin iSAM2 reached
(docs/results.md, "Loops that correct, session 9" and "The graph's basin, session 10").

:func:`staged_solve` solves in two stages: first the *relaxed* graph (every factor whose spec allows
it made non-robust: flow factors plain Gaussian, ``relative_pose`` factors without their Huber kernel),
whose cost is convex-er and pulls the estimate towards the consensus of all factors; then the run's own
graph by LM from there. :func:`one_shot_solve` is the plain LM.

Pure graph code: factors, specs and values in, values out; :class:`gsslam.graph.backend.Backend`
calls it and re-seeds iSAM2 with the result.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import gtsam

from gsslam.graph.factor_specs import FactorSpec, build_factor

__all__ = ["BATCH_SOLVES", "SolveReport", "relaxed_spec", "one_shot_solve", "staged_solve", "solve"]

log = logging.getLogger(__name__)

BATCH_SOLVES = ("lm", "staged")


@dataclass(frozen=True)
class SolveReport:
    """What a batch solve did: the run graph's error at the start and end (and after stage 1)."""

    method: str
    error_initial: float
    error_final: float
    error_relaxed: float | None = None  # the run's graph at the relaxed stage's solution
    relaxed_factors: int = 0  # factors that the relaxed stage changed


def relaxed_spec(s: FactorSpec) -> FactorSpec | None:
    """The non-robust twin of a factor spec, or None when it has no robust part to drop."""
    kind, args, kwargs = s
    if kind in ("flow", "stretched_flow") and kwargs.get("robust", True):
        return kind, args, {**kwargs, "robust": False}
    if kind == "relative_pose":
        # (key_a, key_b, T_a_b, information, huber, group): huber at position 4, or a keyword
        if "huber" in kwargs and float(kwargs["huber"]) > 0:
            return kind, args, {**kwargs, "huber": 0.0}
        if len(args) > 4 and float(args[4]) > 0:
            return kind, (*args[:4], 0.0, *args[5:]), kwargs
    return None


def _lm(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, max_iterations: int) -> gtsam.Values:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    return gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()


def one_shot_solve(
    factors: list[gtsam.NonlinearFactor], initial: gtsam.Values, max_iterations: int
) -> tuple[gtsam.Values, SolveReport]:
    """Levenberg-Marquardt over ``factors`` from ``initial``."""
    graph = gtsam.NonlinearFactorGraph()
    for f in factors:
        graph.add(f)
    result = _lm(graph, initial, max_iterations)
    return result, SolveReport("lm", float(graph.error(initial)), float(graph.error(result)))


def staged_solve(
    factors: list[gtsam.NonlinearFactor],
    specs: list[FactorSpec | None],
    initial: gtsam.Values,
    max_iterations: int,
) -> tuple[gtsam.Values, SolveReport]:
    """LM on the relaxed graph (:func:`relaxed_spec`), then LM on ``factors`` from its solution.

    ``specs[i]`` is the spec of ``factors[i]`` (None: the factor is used as it is in both stages).
    """
    graph, relaxed = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph()
    n_relaxed = 0
    for f, s in zip(factors, specs):
        graph.add(f)
        r = relaxed_spec(s) if s is not None else None
        relaxed.add(f if r is None else build_factor(r))
        n_relaxed += r is not None
    stage1 = _lm(relaxed, initial, max_iterations)
    result = _lm(graph, stage1, max_iterations)
    report = SolveReport(
        "staged",
        float(graph.error(initial)),
        float(graph.error(result)),
        float(graph.error(stage1)),
        n_relaxed,
    )
    log.info(
        "staged batch: %d of %d factors relaxed; error %.6g -> %.6g (relaxed stage) -> %.6g",
        n_relaxed, len(factors), report.error_initial, report.error_relaxed, report.error_final,
    )  # fmt: skip
    return result, report


def solve(
    method: str,
    factors: list[gtsam.NonlinearFactor],
    specs: list[FactorSpec | None],
    initial: gtsam.Values,
    max_iterations: int,
) -> tuple[gtsam.Values, SolveReport]:
    """The batch solve named ``method`` (:data:`BATCH_SOLVES`)."""
    if method == "lm":
        return one_shot_solve(factors, initial, max_iterations)
    if method == "staged":
        return staged_solve(factors, specs, initial, max_iterations)
    raise ValueError(f"unknown batch solve {method!r}; known: {', '.join(BATCH_SOLVES)}")
