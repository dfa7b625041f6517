"""The iSAM2 backend: the only code in gsslam that touches ``gtsam.ISAM2``.

:class:`Backend` buffers new factors and values and sends ONLY those to ``ISAM2.update``. Any gtsam
factor or value is accepted (our custom factors, gtsam's IMU / stereo / GPS factors, ...), so a
user swaps sensors in by adding their own factors; see docs/graph.md. Every factor gets a handle
(an int, stable for the backend's lifetime) that maps to its iSAM2 factor index once it was sent;
:meth:`Backend.remove_factors` removes factors by handle (e.g. a rejected loop) through iSAM2's
``removeFactorIndices`` at the next update.

Replay (checkpoints): a factor added with its *spec* (:mod:`gsslam.graph.factor_specs`, plain data) is
recorded with every value, removal, update and batch refinement in :meth:`Backend.replay_log`, in
order; :meth:`Backend.replay` (:mod:`gsslam.graph.replay`) applies such a log to a fresh backend, which
rebuilds the identical iSAM2 state (same handles, same rejections). A factor added without a spec makes
the log unreplayable.

The backend cannot be poisoned: :meth:`Backend.update` rejects a buffered factor that names a variable
without a value, and when iSAM2 itself fails (an indeterminate system, a factor that throws) it rolls
iSAM2 back to the last good state, finds the buffered factors to blame (each one whose removal makes the
system solvable; the whole batch when no single one does), applies everything else and raises
:class:`RejectedError` naming what it dropped and why. The graph stays usable after the error.

Relinearisation thresholds per key character (:mod:`gsslam.graph.relinearization`): every new value
is checked against the map iSAM2 gets (:meth:`Backend.add_value` refuses a wrong dimension, naming the
key); a new character grows the map and iSAM2 is rebuilt with it before the next update. The errors
live in :mod:`gsslam.graph.rejection` and are importable from here; the solvability checks behind the
blame in :mod:`gsslam.graph.solvability`; the bookkeeping (factors by handle, the buffer, variable types,
the replay log) in :mod:`gsslam.graph.factor_book`.
"""

from __future__ import annotations

import logging
import re

import gtsam
import numpy as np

from gsslam.graph.factor_book import FactorBook
from gsslam.graph.rejection import BATCH_TAG, BackendError, RejectedError, Rejection, first_line
from gsslam.graph.relinearization import RelinearizeThresholds
from gsslam.graph.replay import replay
from gsslam.graph.solvability import new_values_determined, solvable
from gsslam.graph.staged_solve import solve
from gsslam.graph.typed_values import type_name, value_at, value_dim

__all__ = ["Backend", "BackendError", "RejectedError", "Rejection"]

log = logging.getLogger(__name__)


class Backend:
    """Incremental smoothing (iSAM2) over any gtsam factors, plus a batch LM refinement."""

    def __init__(
        self,
        params: gtsam.ISAM2Params | None = None,
        batch_max_iterations: int = 100,
        thresholds: RelinearizeThresholds | None = None,
        batch_solve: str = "lm",
    ):
        self._params = params if params is not None else gtsam.ISAM2Params()
        # per-character relinearisation thresholds, checked against every new value (None: whatever
        # ``params`` holds, unchecked)
        self._thresholds = thresholds
        self._thresholds_grew = False  # a new key character: iSAM2 is rebuilt before the next update
        if thresholds is not None:
            thresholds.apply(self._params)
        self._isam = gtsam.ISAM2(self._params)
        self._batch_max_iterations = batch_max_iterations
        self._batch_solve = batch_solve  # refine_batch's method (gsslam.graph.staged_solve)
        self._book = FactorBook()  # factors by handle, the buffer of the next update, types, the log
        self._estimate: gtsam.Values | None = None
        self.last_result: gtsam.ISAM2Result | None = None
        self.last_batch = None  # the SolveReport of the last refine_batch
        self.config = None  # the GraphConfig it was made from (from_config), for a replay

    @classmethod
    def from_config(cls, cfg) -> Backend:  # cfg: gsslam.config.GraphConfig
        from gsslam.graph.noise import isam_params

        thresholds = RelinearizeThresholds.from_config(cfg)
        backend = cls(isam_params(cfg), cfg.batch_max_iterations, thresholds, cfg.batch_solve)
        backend.config = cfg
        return backend

    # -- replay -----------------------------------------------------------------------------
    def replay_log(self) -> list[tuple]:
        """Every change so far as plain data: ``("factor", name, spec)``, ``("value", key, value)``,
        ``("remove", handles)``, ``("update", extra_iterations)``, ``("batch", max_iterations)``.

        Raises :class:`BackendError` when a factor was added without a spec (e.g. by a plugin) or the
        backend was not made by :meth:`from_config`.
        """
        if self._book.unreplayable is not None:
            raise BackendError(f"this graph cannot be checkpointed: {self._book.unreplayable}")
        if self.config is None:
            raise BackendError("this graph cannot be checkpointed: its backend was not made from a config")
        return list(self._book.log)

    def replay(self, log: list[tuple], build) -> None:
        """Apply a :meth:`replay_log` to this (fresh) backend; ``build(spec)`` makes each factor
        (:func:`gsslam.graph.replay.replay`: rejected updates are passed over, as the original caller did).
        """
        replay(self, log, build)

    # -- building ---------------------------------------------------------------------------
    def add_factor(self, factor: gtsam.NonlinearFactor, name: str | None = None, spec=None) -> int:
        """Buffer ``factor`` for the next :meth:`update`; returns its handle.

        ``name`` appears in every message about the factor (e.g. when :meth:`update` rejects it).
        ``spec``: the factor as plain data (:mod:`gsslam.graph.factor_specs`), for :meth:`replay`.
        """
        if factor is None or not isinstance(factor, gtsam.NonlinearFactor):
            raise BackendError(f"add_factor needs a gtsam factor, got {type(factor).__name__}")
        return self._book.add_factor(factor, name, spec)

    def add_value(self, key: int, value) -> None:
        """Buffer the initial value of a NEW variable ``key`` (any gtsam value type).

        With per-character relinearisation thresholds, a value whose dimension differs from its key
        character's entry raises :class:`BackendError` (nothing is buffered).
        """
        if self.has_value(key):
            raise BackendError(f"variable {gtsam.DefaultKeyFormatter(key)} already has a value")
        if self._thresholds is not None:
            self._thresholds_grew |= self._thresholds.admit(key, value_dim(value), type_name(value))
        self._book.add_value(key, value)

    def has_value(self, key: int) -> bool:
        return self._book.has_value(key)

    def remove_factors(self, handles: list[int]) -> None:
        """Remove factors by handle; sent ones leave iSAM2 at the next :meth:`update`."""
        self._book.remove(handles)

    def live_specs(self) -> list[tuple]:
        """The specs of the live factors (added with a spec, not removed or rejected), in handle order."""
        return self._book.live_specs()

    def describe_factor(self, handle: int) -> str:
        """``factor 'name' (Type on s0,s1)`` or ``factor #12 (Type on s0,s1)`` (for messages)."""
        return self._book.describe(handle)

    # -- solving ----------------------------------------------------------------------------
    def update(self, extra_iterations: int = 0) -> gtsam.ISAM2Result | None:
        """One iSAM2 update with the buffered factors, values and removals (+ optional extra steps).

        Raises :class:`RejectedError` after applying everything else when some buffered factors or
        values had to be dropped (see the module doc); the backend stays usable.
        """
        book = self._book
        book.log.append(("update", int(extra_iterations)))
        if not book.pending and not book.to_remove and book.new_values.size() == 0 and not extra_iterations:
            return None
        rejected = book.reject_missing_keys()
        if self._thresholds_grew:
            self._rebuild_with_thresholds()
        try:
            result = self._send()
        except Exception as e:  # noqa: BLE001 - gtsam and user factors throw anything; we roll back
            self._rollback()
            result = self._retry_with_qr(e)
            if result is None:
                rejected += self._blame(e)
                result = self._send()  # the rest; _blame made sure it is solvable
        for _ in range(extra_iterations):
            result = self._isam.update()
        self._estimate = None
        self.last_result = result
        if rejected:
            for r in rejected:
                log.warning("backend rejected %s: %s", r.what, r.cause)
            raise RejectedError(rejected)
        return result

    def _rebuild_with_thresholds(self) -> None:
        """A variable brought a key character the threshold map lacked: iSAM2 copies its parameters
        when made, so a new one takes the grown map, re-seeded with the sent factors at the estimate."""
        self._thresholds.apply(self._params)
        self._thresholds_grew = False
        sent = self._book.sent()
        log.info(
            "relinearisation thresholds for key characters %s: iSAM2 rebuilt", sorted(self._thresholds.dims)
        )
        if not sent and not self._book.to_remove:
            self._isam = gtsam.ISAM2(self._params)
            return
        estimate = self._isam.calculateEstimate()
        graph = self._book.graph(sent)
        self._isam = gtsam.ISAM2(self._params)
        res = self._isam.update(graph, estimate)
        self._book.reindex(sent, res.getNewFactorsIndices())
        self._book.to_remove = []
        self._estimate = None

    def _send(self) -> gtsam.ISAM2Result:
        book = self._book
        graph = book.graph(book.pending)
        result = self._isam.update(graph, book.new_values, [book.index[h] for h in book.to_remove])
        book.mark_sent(result.getNewFactorsIndices())
        return result

    def _rollback(self) -> None:
        """iSAM2 threw mid-update (it is half-changed): rebuild it from the factors it held before."""
        book = self._book
        theta = self._isam.getLinearizationPoint()
        old = gtsam.Values()
        for k in theta.keys():
            if k in book.types and not book.new_values.exists(k):
                old.insert(k, value_at(theta, k, book.types[k]))
        sent = book.sent()  # removals of this update still apply
        graph = book.graph(sent)
        self._isam = gtsam.ISAM2(self._params)
        res = self._isam.update(graph, old)
        book.reindex(sent, res.getNewFactorsIndices())
        book.to_remove = []
        self._estimate = None
        self._sent_graph, self._sent_values = graph, old

    def _retry_with_qr(self, error: Exception) -> gtsam.ISAM2Result | None:
        """An indeterminate system under Cholesky may only be poorly conditioned: QR (slower, but
        without squaring the condition number) solves it; the backend keeps QR from then on."""
        if "ndeterminate" not in str(error) or self._params.getFactorization() == "QR":
            return None
        near, new = re.search(r"variable\s+(\d+)", str(error)), self._book.new_values
        if near is None or new.exists(int(near.group(1))) or not self._new_values_determined():
            return None  # a new variable is under-constrained: QR would hide it (it does not check rank)
        self._params.setFactorization("QR")
        sent = list(self._book.index)
        self._isam = gtsam.ISAM2(self._params)
        res = self._isam.update(self._sent_graph, self._sent_values)
        self._book.reindex(sent, res.getNewFactorsIndices())
        try:
            result = self._send()
        except Exception:  # noqa: BLE001 - not a conditioning problem: back to Cholesky, blame factors
            self._params.setFactorization("CHOLESKY")
            self._rollback()
            return None
        log.warning(
            "iSAM2 (Cholesky) failed: %s; solved with QR factorization, which the graph uses from now on",
            first_line(error),
        )
        return result

    def _new_values_determined(self) -> bool:
        book = self._book
        pending = [book.factors[h] for h in book.pending]
        return new_values_determined(pending, self._sent_values, book.new_values, book.types)

    def _blame(self, error: Exception) -> list[Rejection]:
        """Drop the buffered culprits of a failed update (iSAM2 was rolled back)."""
        book, cause = self._book, first_line(error)
        graph = self._sent_graph
        # blame: each buffered factor whose removal alone makes the system solvable
        values = gtsam.Values(self._sent_values)
        values.insert(book.new_values)
        blamed = [h for h in book.pending if self._solvable(graph, values, skip=h)]
        if blamed and (len(blamed) < len(book.pending) or len(book.pending) == 1):
            out = [book.drop_pending(h, cause) for h in blamed]
            out += book.reject_unused_values()
            if self._solvable(graph, values, skip=None):
                return out
        else:
            out = []
        # no single culprit (or several together): the whole batch goes
        for h in list(book.pending):
            out.append(book.drop_pending(h, cause + BATCH_TAG))
        for k in list(book.new_values.keys()):
            out.append(book.drop_new_value(k, "rolled back with its batch" + BATCH_TAG))
        return out

    def _solvable(self, sent: gtsam.NonlinearFactorGraph, values: gtsam.Values, skip: int | None) -> bool:
        book = self._book
        return solvable(sent, values, [book.factors[h] for h in book.pending if h != skip], book.types)

    def refine_batch(self, max_iterations: int | None = None) -> float:
        """The whole graph solved from the current estimate (Levenberg-Marquardt, one-shot or staged:
        :mod:`gsslam.graph.staged_solve`), then iSAM2 re-seeded with the result.

        Pending factors and values are included. Handles stay valid. Returns the final error.
        """
        book = self._book
        book.log.append(("batch", max_iterations))
        rejected = book.reject_missing_keys()
        handles = sorted(book.factors)
        factors = [book.factors[h] for h in handles]
        specs = [book.specs.get(h) for h in handles]
        initial = gtsam.Values(self.values())
        try:
            result, report = solve(
                self._batch_solve, factors, specs, initial,
                max_iterations or self._batch_max_iterations,
            )  # fmt: skip
        except RuntimeError as e:  # nothing was changed: the iSAM2 state is still the last good one
            raise BackendError(f"batch refinement failed, graph unchanged: {first_line(e)}") from e
        log.debug("batch %s: error %.6g -> %.6g", report.method, report.error_initial, report.error_final)
        self.last_batch = report
        graph = book.graph(handles)
        if self._thresholds_grew:  # a key character new since the last update
            self._thresholds.apply(self._params)
            self._thresholds_grew = False
        self._isam = gtsam.ISAM2(self._params)
        res = self._isam.update(graph, result)
        book.reindex(handles, res.getNewFactorsIndices())
        book.clear_buffer()
        self._estimate = None
        if rejected:
            raise RejectedError(rejected)
        return report.error_final

    # -- reading ----------------------------------------------------------------------------
    def values(self) -> gtsam.Values:
        """Current estimate of every variable (pending values included as given)."""
        if self._estimate is None:
            self._estimate = self._isam.calculateEstimate()
        if self._book.new_values.size() == 0:
            return self._estimate
        out = gtsam.Values(self._estimate)
        out.insert(self._book.new_values)
        return out

    def estimate(self, key: int):
        """Current estimate of one variable, as its gtsam type."""
        types = self._book.types
        if key not in types:
            raise BackendError(f"unknown variable {gtsam.DefaultKeyFormatter(key)}")
        at = getattr(gtsam.Values, f"at{types[key]}")
        if self._book.new_values.exists(key):
            return at(self._book.new_values, key)
        if self._estimate is not None:
            return at(self._estimate, key)
        return getattr(self._isam, f"calculateEstimate{types[key]}")(key)

    def marginal_covariance(self, key: int) -> np.ndarray:
        """Marginal covariance of ``key`` in its tangent space (call :meth:`update` first)."""
        if key not in self._book.types or self._book.new_values.exists(key):
            raise BackendError(
                f"variable {gtsam.DefaultKeyFormatter(key)} is not in iSAM2 yet; call update()"
            )
        return np.asarray(self._isam.marginalCovariance(key))

    def error(self) -> float:
        """Total nonlinear error of the live factors at the current estimate."""
        return float(self._book.graph(sorted(self._book.factors)).error(self.values()))

    def factor(self, handle: int) -> gtsam.NonlinearFactor:
        return self._book.factors[handle]

    def factor_index(self, handle: int) -> int | None:
        """iSAM2 factor index of a sent factor (None while pending)."""
        return self._book.index.get(handle)

    @property
    def num_factors(self) -> int:
        return len(self._book.factors)

    @property
    def isam_size(self) -> int:
        """Number of variables in iSAM2 (``ISAM2.size()`` counts Bayes-tree cliques, not variables)."""
        return int(self._isam.getLinearizationPoint().size())
