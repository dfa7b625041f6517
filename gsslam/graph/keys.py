"""Symbol conventions of the factor graph.

- ``S(i)``: submap ``i``'s transform ``T_world_local_i`` (gtsam.Similarity3), character ``s``.
- ``X(k)``: a keyframe pose ``T_world_cam`` (gtsam.Pose3), character ``x``, keyed by dataset frame index.
- any other character is free for user variables (IMU velocities ``v``, biases ``b``, landmarks ``l``).
"""

from __future__ import annotations

import gtsam

RESERVED = ("s", "x")


def submap_key(i: int) -> int:
    return gtsam.symbol("s", int(i))


def keyframe_key(frame_index: int) -> int:
    return gtsam.symbol("x", int(frame_index))


def user_key(char: str, index: int) -> int:
    """A key for user variables; ``char`` must not be one of the reserved characters ``s``, ``x``."""
    from gsslam.graph.backend import BackendError

    if len(char) != 1 or char in RESERVED:
        raise BackendError(f"user keys need one character other than {RESERVED}, got {char!r}")
    return gtsam.symbol(char, int(index))


def describe(key: int) -> str:
    """``'s12'``-style name of a key (for messages)."""
    sym = gtsam.Symbol(key)
    return f"{chr(sym.chr())}{sym.index()}"
