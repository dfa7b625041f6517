"""Replaying a backend's log (checkpoints): apply :meth:`Backend.replay_log` to a fresh backend.

A factor added with its *spec* (:mod:`gsslam.graph.factor_specs`, plain data) is recorded with every
value, removal, update and batch refinement in the backend's replay log, in order; :func:`replay`
applies such a log to a fresh backend, which rebuilds the identical iSAM2 state (same handles, same
rejections). A factor added without a spec makes the log unreplayable.
"""

from __future__ import annotations

from gsslam.graph.rejection import BackendError, RejectedError


def replay(backend, log: list[tuple], build) -> None:
    """Apply a replay log to ``backend`` (a fresh :class:`~gsslam.graph.backend.Backend`);
    ``build(spec)`` makes each factor.

    Updates and batch refinements that were rejected or failed in the original run fail here in
    the same way and are passed over, as the original caller did.
    """
    for op in log:
        kind = op[0]
        if kind == "factor":
            backend.add_factor(build(op[2]), op[1], spec=op[2])
        elif kind == "value":
            backend.add_value(int(op[1]), op[2])
        elif kind == "remove":
            backend.remove_factors([int(h) for h in op[1]])
        elif kind == "update":
            try:
                backend.update(int(op[1]))
            except RejectedError:
                pass
        elif kind == "batch":
            try:
                backend.refine_batch(op[1])
            except BackendError:
                pass
        else:
            raise BackendError(f"unknown operation {kind!r} in a replay log")
