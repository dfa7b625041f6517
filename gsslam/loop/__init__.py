"""gsslam.loop: loop closure between submaps (detection, verification, consistency checks).

The module returns :class:`LoopConstraint` objects; it never edits the graph. See
docs/loop_closure.md for the data flow and how the pipeline uses it.
"""

from gsslam.loop.consistency import check_loops, drift_gate, propagate_correction
from gsslam.loop.detector import LoopDetector
from gsslam.loop.types import LoopCandidate, LoopConstraint, LoopError, LoopStats, Verdict

__all__ = [
    "LoopCandidate",
    "LoopConstraint",
    "LoopDetector",
    "LoopError",
    "LoopStats",
    "Verdict",
    "check_loops",
    "drift_gate",
    "propagate_correction",
]
