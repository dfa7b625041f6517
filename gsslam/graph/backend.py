"""The iSAM2 backend: the only code in gsslam that touches ``gtsam.ISAM2``.

:class:`Backend` buffers new factors and values and sends ONLY those to ``ISAM2.update``. Any gtsam
factor or value is accepted (our custom factors, gtsam's IMU / stereo / GPS factors, ...), so a
user swaps sensors in by adding their own factors; see docs/graph.md. Every factor gets a handle
(an int, stable for the backend's lifetime) that maps to its iSAM2 factor index once it was sent;
:meth:`Backend.remove_factors` removes factors by handle (e.g. a rejected loop) through iSAM2's
``removeFactorIndices`` at the next update.
"""

from __future__ import annotations

import logging

import gtsam
import numpy as np

from gsslam.errors import GsslamError

log = logging.getLogger(__name__)


class BackendError(GsslamError):
    """A factor or value the backend cannot use (unknown key, duplicate value, unknown handle)."""


def _type_name(value) -> str:
    if isinstance(value, (float, int)):
        return "Double"
    if isinstance(value, np.ndarray):
        return "Vector"
    if isinstance(value, gtsam.imuBias.ConstantBias):
        return "ConstantBias"
    return type(value).__name__


class Backend:
    """Incremental smoothing (iSAM2) over any gtsam factors, plus a batch LM refinement."""

    def __init__(self, params: gtsam.ISAM2Params | None = None, batch_max_iterations: int = 100):
        self._params = params if params is not None else gtsam.ISAM2Params()
        self._isam = gtsam.ISAM2(self._params)
        self._batch_max_iterations = batch_max_iterations
        self._factors: dict[int, gtsam.NonlinearFactor] = {}  # live factors by handle
        self._index: dict[int, int] = {}  # handle -> iSAM2 factor index (sent factors)
        self._pending: list[int] = []  # handles not yet sent
        self._to_remove: list[int] = []  # handles of sent factors to remove at the next update
        self._new_values = gtsam.Values()
        self._types: dict[int, str] = {}  # key -> gtsam type name (for typed estimates)
        self._next_handle = 0
        self._estimate: gtsam.Values | None = None
        self.last_result: gtsam.ISAM2Result | None = None

    @classmethod
    def from_config(cls, cfg) -> Backend:  # cfg: gsslam.config.GraphConfig
        from gsslam.graph.noise import isam_params

        return cls(isam_params(cfg), cfg.batch_max_iterations)

    # -- building ---------------------------------------------------------------------------
    def add_factor(self, factor: gtsam.NonlinearFactor) -> int:
        """Buffer ``factor`` for the next :meth:`update`; returns its handle."""
        if factor is None:
            raise BackendError("add_factor got None; pass a gtsam factor")
        handle = self._next_handle
        self._next_handle += 1
        self._factors[handle] = factor
        self._pending.append(handle)
        return handle

    def add_value(self, key: int, value) -> None:
        """Buffer the initial value of a NEW variable ``key`` (any gtsam value type)."""
        if self.has_value(key):
            raise BackendError(f"variable {gtsam.DefaultKeyFormatter(key)} already has a value")
        self._new_values.insert(key, value)
        self._types[key] = _type_name(value)

    def has_value(self, key: int) -> bool:
        return key in self._types

    def remove_factors(self, handles: list[int]) -> None:
        """Remove factors by handle; sent ones leave iSAM2 at the next :meth:`update`."""
        for h in handles:
            if h not in self._factors:
                raise BackendError(f"unknown or already removed factor handle {h}")
            del self._factors[h]
            if h in self._index:
                self._to_remove.append(h)
            else:
                self._pending.remove(h)

    # -- solving ----------------------------------------------------------------------------
    def update(self, extra_iterations: int = 0) -> gtsam.ISAM2Result | None:
        """One iSAM2 update with the buffered factors, values and removals (+ optional extra steps)."""
        if (
            not self._pending
            and not self._to_remove
            and self._new_values.size() == 0
            and not extra_iterations
        ):
            return None
        graph = gtsam.NonlinearFactorGraph()
        for h in self._pending:
            self._check_keys(self._factors[h])
            graph.add(self._factors[h])
        remove = [self._index.pop(h) for h in self._to_remove]
        try:
            result = self._isam.update(graph, self._new_values, remove)
        except RuntimeError as e:
            raise BackendError(f"iSAM2 update failed: {e}") from e
        for h, idx in zip(self._pending, result.getNewFactorsIndices()):
            self._index[h] = int(idx)
        self._pending, self._to_remove, self._new_values = [], [], gtsam.Values()
        for _ in range(extra_iterations):
            result = self._isam.update()
        self._estimate = None
        self.last_result = result
        return result

    def _check_keys(self, factor) -> None:
        for k in factor.keys():
            if k not in self._types:
                raise BackendError(
                    f"a factor uses variable {gtsam.DefaultKeyFormatter(k)} that has no value; "
                    "call add_value(key, initial_value) first"
                )

    def refine_batch(self, max_iterations: int | None = None) -> float:
        """Levenberg-Marquardt over the whole graph from the current estimate, then re-seed iSAM2.

        Pending factors and values are included. Handles stay valid. Returns the final error.
        """
        handles = sorted(self._factors)
        graph = gtsam.NonlinearFactorGraph()
        for h in handles:
            self._check_keys(self._factors[h])
            graph.add(self._factors[h])
        initial = gtsam.Values(self.values())
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(max_iterations or self._batch_max_iterations)
        result = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
        error = float(graph.error(result))
        log.debug("batch LM: error %.6g -> %.6g", graph.error(initial), error)
        self._isam = gtsam.ISAM2(self._params)
        res = self._isam.update(graph, result)
        self._index = {h: int(i) for h, i in zip(handles, res.getNewFactorsIndices())}
        self._pending, self._to_remove, self._new_values = [], [], gtsam.Values()
        self._estimate = None
        return error

    # -- reading ----------------------------------------------------------------------------
    def values(self) -> gtsam.Values:
        """Current estimate of every variable (pending values included as given)."""
        if self._estimate is None:
            self._estimate = self._isam.calculateEstimate()
        if self._new_values.size() == 0:
            return self._estimate
        out = gtsam.Values(self._estimate)
        out.insert(self._new_values)
        return out

    def estimate(self, key: int):
        """Current estimate of one variable, as its gtsam type."""
        if key not in self._types:
            raise BackendError(f"unknown variable {gtsam.DefaultKeyFormatter(key)}")
        at = getattr(gtsam.Values, f"at{self._types[key]}")
        if self._new_values.exists(key):
            return at(self._new_values, key)
        if self._estimate is not None:
            return at(self._estimate, key)
        return getattr(self._isam, f"calculateEstimate{self._types[key]}")(key)

    def marginal_covariance(self, key: int) -> np.ndarray:
        """Marginal covariance of ``key`` in its tangent space (call :meth:`update` first)."""
        if key not in self._types or self._new_values.exists(key):
            raise BackendError(
                f"variable {gtsam.DefaultKeyFormatter(key)} is not in iSAM2 yet; call update()"
            )
        return np.asarray(self._isam.marginalCovariance(key))

    def error(self) -> float:
        """Total nonlinear error of the live factors at the current estimate."""
        graph = gtsam.NonlinearFactorGraph()
        for h in sorted(self._factors):
            graph.add(self._factors[h])
        return float(graph.error(self.values()))

    def factor(self, handle: int) -> gtsam.NonlinearFactor:
        return self._factors[handle]

    def factor_index(self, handle: int) -> int | None:
        """iSAM2 factor index of a sent factor (None while pending)."""
        return self._index.get(handle)

    @property
    def num_factors(self) -> int:
        return len(self._factors)

    @property
    def isam_size(self) -> int:
        """Number of variables in iSAM2 (``ISAM2.size()`` counts Bayes-tree cliques, not variables)."""
        return int(self._isam.getLinearizationPoint().size())
