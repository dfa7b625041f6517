"""The backend's book of its graph: factors by handle, the buffer of the next update, the replay log.

:class:`FactorBook` is what :class:`gsslam.graph.backend.Backend` knows about its graph besides iSAM2
itself (it never touches iSAM2): the live factors by handle (an int, stable for the backend's lifetime)
with their names and specs, the iSAM2 factor index of every sent factor, the buffer of the next update
(new factors, removals of sent ones, new values), the gtsam type of every variable, and the replay log
(every change in order, as plain data; :mod:`gsslam.graph.replay`). It drops from the buffer what
iSAM2 must not get: a factor that names a variable without a value, a new value no factor constrains.
"""

from __future__ import annotations

import gtsam
import numpy as np

from gsslam.graph.rejection import BackendError, Rejection
from gsslam.graph.typed_values import factor_keys, type_name


class FactorBook:
    """Factors by handle, sent or buffered; new values; variable types; the replay log."""

    def __init__(self) -> None:
        self.factors: dict[int, gtsam.NonlinearFactor] = {}  # live factors by handle
        self.index: dict[int, int] = {}  # handle -> iSAM2 factor index (sent factors)
        self.pending: list[int] = []  # handles not yet sent
        self.to_remove: list[int] = []  # handles of sent factors to remove at the next update
        self.new_values = gtsam.Values()
        self.types: dict[int, str] = {}  # key -> gtsam type name (for typed estimates)
        self.names: dict[int, str] = {}  # handle -> user-given name
        self.specs: dict[int, tuple] = {}  # handle -> factor spec (factors added with one)
        self.log: list[tuple] = []  # every change, in order, as plain data (Backend.replay_log)
        self.unreplayable: str | None = None  # why the log cannot rebuild the backend
        self._next_handle = 0

    # -- changes ------------------------------------------------------------------------------
    def add_factor(self, factor: gtsam.NonlinearFactor, name: str | None, spec) -> int:
        """Buffer ``factor``; returns its handle (a factor without ``spec`` makes the log unreplayable)."""
        handle = self._next_handle
        self._next_handle += 1
        self.factors[handle] = factor
        if name:
            self.names[handle] = str(name)
        self.pending.append(handle)
        if spec is not None:
            self.specs[handle] = spec
        if spec is None:
            self.unreplayable = self.unreplayable or f"{self.describe(handle)} was added without a spec"
        self.log.append(("factor", name, spec))
        return handle

    def add_value(self, key: int, value) -> None:
        """Buffer the value of a new variable ``key`` (the caller checked it has none yet)."""
        self.new_values.insert(key, value)
        self.types[key] = type_name(value)
        if not isinstance(value, (gtsam.Similarity3, gtsam.Pose3, np.ndarray)):
            self.unreplayable = (
                self.unreplayable or f"value {gtsam.DefaultKeyFormatter(key)} is a {type_name(value)}"
            )
        self.log.append(("value", int(key), value))

    def remove(self, handles: list[int]) -> None:
        """Remove factors by handle: buffered ones at once, sent ones at the next update."""
        for h in handles:
            if h not in self.factors:
                raise BackendError(f"unknown or already removed factor handle {h}")
            del self.factors[h]
            self.names.pop(h, None)
            if h in self.index:
                self.to_remove.append(h)
            else:
                self.pending.remove(h)
        self.log.append(("remove", [int(h) for h in handles]))

    def mark_sent(self, new_indices) -> None:
        """The buffer went to iSAM2 (``new_indices``: its indices of the pending factors): removed
        factors leave the index, pending ones enter it, the buffer is empty."""
        for h in self.to_remove:
            del self.index[h]
        for h, idx in zip(self.pending, new_indices):
            self.index[h] = int(idx)
        self.clear_buffer()

    def reindex(self, handles: list[int], new_indices) -> None:
        """iSAM2 was rebuilt from the factors ``handles``, in order: their new indices."""
        self.index = {h: int(i) for h, i in zip(handles, new_indices)}

    def clear_buffer(self) -> None:
        self.pending, self.to_remove, self.new_values = [], [], gtsam.Values()

    # -- rejections ---------------------------------------------------------------------------
    def drop_pending(self, handle: int, cause: str) -> Rejection:
        r = Rejection(self.describe(handle), cause, handle=handle)
        self.pending.remove(handle)
        del self.factors[handle]
        self.names.pop(handle, None)
        return r

    def drop_new_value(self, key: int, cause: str) -> Rejection:
        r = Rejection(f"value {gtsam.DefaultKeyFormatter(key)} ({self.types[key]})", cause, key=key)
        self.new_values.erase(key)
        del self.types[key]
        return r

    def reject_missing_keys(self) -> list[Rejection]:
        """Buffered factors that name a variable without a value, then new values left unconstrained."""
        out = []
        for h in list(self.pending):
            missing = [k for k in self.factors[h].keys() if k not in self.types]
            if missing:
                names = ",".join(gtsam.DefaultKeyFormatter(k) for k in missing)
                out.append(self.drop_pending(h, f"missing key {names}: no value; call add_value first"))
        return out + self.reject_unused_values()

    def reject_unused_values(self) -> list[Rejection]:
        """New values no buffered factor constrains (sent factors cannot name them) would be singular."""
        used = {k for h in self.pending for k in self.factors[h].keys()}
        return [
            self.drop_new_value(k, "no factor constrains it")
            for k in list(self.new_values.keys())
            if k not in used
        ]

    # -- reading ------------------------------------------------------------------------------
    def has_value(self, key: int) -> bool:
        return key in self.types

    def sent(self) -> list[int]:
        """Handles of the live factors iSAM2 holds, in index order (removals of this update still apply)."""
        return [h for h in self.index if h in self.factors]

    def graph(self, handles) -> gtsam.NonlinearFactorGraph:
        """The factors ``handles`` as one graph, in order."""
        graph = gtsam.NonlinearFactorGraph()
        for h in handles:
            graph.add(self.factors[h])
        return graph

    def live_specs(self) -> list[tuple]:
        """The specs of the live factors (added with a spec, not removed or rejected), in handle order."""
        return [self.specs[h] for h in sorted(self.factors) if h in self.specs]

    def describe(self, handle: int) -> str:
        """``factor 'name' (Type on s0,s1)`` or ``factor #12 (Type on s0,s1)`` (for messages)."""
        f = self.factors[handle]
        label = repr(self.names[handle]) if handle in self.names else f"#{handle}"
        return f"factor {label} ({type(f).__name__} on {factor_keys(f)})"
