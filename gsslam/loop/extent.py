"""How wide a loop's points are across its narrowest in-plane direction: what sets its rotation error.

A mono loop's Sim(3) is fitted to point pairs of two point maps whose depths carry a smooth,
correlated error of a few percent (the triangulation of one submap against the other's). That error
does not average out over the points, so the loop's rotation error is not its inlier noise over
sqrt(N) but about (depth error) / (lever arm): a loop whose points lie on a narrow strip (a table
edge, one object) turns by degrees. The lever arm is the points' second principal standard deviation
(the spread of the middle axis of their covariance), taken relative to their median range so that it
is unit-free (mono units are arbitrary). Measured on teddy mono runs (docs/results.md, "Mono loops to
the first submap, session 12"): Spearman -0.47 ... -0.77 between it and the loop's rotation error
against the ground truth; loops below 0.1 are 2.6-3.2 deg off (median), the others 1.0-1.4.

``loop.mono_extent_sigma`` (0: off) multiplies a mono loop's sigmas by ``max(1, it / extent)``.
"""

from __future__ import annotations

import numpy as np


def lateral_extent_rel(X: np.ndarray) -> float:  # X [N, 3], one submap's local points
    """Second principal standard deviation of ``X`` over its median distance from the origin (the
    submap's camera); 0 for fewer than 3 points."""
    if len(X) < 3:
        return 0.0
    ev = np.linalg.eigvalsh(np.cov((X - X.mean(0)).T))  # ascending
    r = float(np.median(np.linalg.norm(X, axis=1)))
    return float(np.sqrt(max(ev[1], 0.0)) / max(r, 1e-12))
