"""Can iSAM2 solve it? Checks on the linear system the backend uses to find the factors to blame.

Pure functions of gtsam factors and values (nothing is changed); :class:`gsslam.graph.backend.Backend`
calls them after a failed update.
"""

from __future__ import annotations

import gtsam
import numpy as np

from gsslam.graph.typed_values import dim_at, value_at


def new_values_determined(
    pending: list[gtsam.NonlinearFactor],
    sent_values: gtsam.Values,
    new_values: gtsam.Values,
    types: dict[int, str],
) -> bool:
    """Does each new variable get full-rank information from the buffered factors on it alone?

    ``pending``: the buffered factors, in order; ``types``: key -> gtsam type name of every variable.
    """
    values = gtsam.Values(sent_values)
    values.insert(new_values)
    for k in new_values.keys():
        info = None
        for f in pending:
            keys = list(f.keys())
            if k not in keys:
                continue
            try:
                A, _ = f.linearize(values).jacobian()
            except Exception:  # noqa: BLE001 - a factor that cannot linearize is for the blame
                return False
            dims = [dim_at(values, kk, types[kk]) for kk in keys]
            start = sum(dims[: keys.index(k)])
            Ak = np.asarray(A)[:, start : start + dims[keys.index(k)]]
            info = Ak.T @ Ak if info is None else info + Ak.T @ Ak
        if info is None:
            return False
        ev = np.linalg.eigvalsh(info)
        if ev[0] <= 1e-9 * max(ev[-1], 1e-300):
            return False
    return True


def solvable(
    sent: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    factors: list[gtsam.NonlinearFactor],
    types: dict[int, str],
) -> bool:
    """Does the graph ``sent`` plus ``factors`` eliminate at ``values`` (the keys they use)?"""
    graph = gtsam.NonlinearFactorGraph(sent)
    keys = set(values.keys())
    for f in factors:
        graph.add(f)
    used = {k for i in range(graph.size()) if graph.at(i) is not None for k in graph.at(i).keys()}
    vals = gtsam.Values()
    for k in keys & used:
        vals.insert(k, value_at(values, k, types[k]))
    try:
        graph.linearize(vals).eliminateMultifrontal()
        return True
    except Exception:  # noqa: BLE001
        return False
