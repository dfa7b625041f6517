"""iSAM2 relinearisation thresholds per key character, checked against every variable.

iSAM2 relinearises a variable when its delta exceeds the threshold: one scalar for all, or a map from
key character to a vector with one entry per tangent dimension (``gtsam.ISAM2ThresholdMap``). gtsam
looks a variable's character up in that map without checking that it is there or that the vector has
the variable's dimension (a 6-vector on a 3-dim velocity runs silently and reads past it).
:class:`RelinearizeThresholds` makes the map safe: it sizes every entry from the variables themselves
(:meth:`admit`, called by the backend for each new value) and refuses a variable whose dimension
differs from the entry of its character, naming the key. A character nobody declared (a plugin's
variable) gets the scalar threshold at its dimension; the backend then rebuilds iSAM2 with the grown
map once before its next update. Without per-character overrides the scalar threshold is used and
nothing is checked.
"""

from __future__ import annotations

import gtsam
import numpy as np

from gsslam.graph.rejection import BackendError

# tangent dimension of the characters gsslam's graphs use (keys.py; IMU states in graph/imu.py)
KNOWN_DIMS = {"s": 7, "x": 6, "v": 3, "b": 6}


class RelinearizeThresholds:
    """A scalar threshold plus per-character overrides (a float, or one value per tangent dimension)."""

    def __init__(self, default: float, overrides: dict[str, float | list[float]] | None = None):
        self.default = float(default)
        self.overrides = {str(c): np.atleast_1d(np.asarray(v, float)) for c, v in (overrides or {}).items()}
        for c, v in self.overrides.items():
            if len(c) != 1:
                raise BackendError(f"relinearisation threshold for {c!r}: key characters are one letter")
            if np.any(v < 0):
                raise BackendError(f"relinearisation threshold for {c!r} is negative: {v.tolist()}")
        # characters of the map and their dimensions: the known ones, then every admitted variable's
        self.dims: dict[str, int] = dict(KNOWN_DIMS) if self.typed else {}
        for c, v in self.overrides.items():
            if len(v) > 1 and c in self.dims and len(v) != self.dims[c]:
                raise BackendError(
                    f"relinearisation threshold for {c!r} has {len(v)} entries; "
                    f"{c!r} variables have dimension {self.dims[c]}"
                )

    @classmethod
    def from_config(cls, cfg) -> RelinearizeThresholds:  # cfg: gsslam.config.GraphConfig
        over = {}
        for c, value in (("v", cfg.relinearize_threshold_velocity), ("b", cfg.relinearize_threshold_bias)):
            if value > 0 and value != cfg.relinearize_threshold:
                over[c] = value
        return cls(cfg.relinearize_threshold, over)

    @property
    def typed(self) -> bool:
        """Does iSAM2 get a per-character map (True) or the scalar threshold (False)?"""
        return bool(self.overrides)

    def admit(self, key: int, dim: int, type_name: str = "") -> bool:
        """Check a new variable against the map; True when its character is new (the map grew).

        Raises :class:`BackendError` naming the key when the map holds another dimension for its
        character (iSAM2 would read a wrong-sized threshold for it).
        """
        if not self.typed:
            return False
        c = chr(gtsam.Symbol(key).chr())
        name = f"{c}{gtsam.Symbol(key).index()}"
        what = f"variable {name}" + (
            f" ({type_name}, dimension {dim})" if type_name else f" (dimension {dim})"
        )
        v = self.overrides.get(c)
        if v is not None and len(v) > 1 and len(v) != dim:
            raise BackendError(
                f"{what}: the relinearisation threshold for key character {c!r} has {len(v)} entries; "
                f"give one per dimension ({dim}) or a single value"
            )
        if c in self.dims:
            if self.dims[c] != dim:
                raise BackendError(
                    f"{what}: key character {c!r} is for variables of dimension {self.dims[c]} in the "
                    f"per-character relinearisation thresholds; put this variable under another character"
                )
            return False
        self.dims[c] = int(dim)
        return True

    def vector(self, c: str) -> np.ndarray:  # [dims[c]]
        v = self.overrides.get(c, np.array([self.default]))
        return np.full(self.dims[c], float(v[0])) if len(v) == 1 else v.copy()

    def apply(self, params: gtsam.ISAM2Params) -> None:
        """Set the scalar threshold or the map (every admitted character, sized) on ``params``."""
        if not self.typed:
            params.setRelinearizeThreshold(self.default)
            return
        m = gtsam.ISAM2ThresholdMap()
        for c in sorted(self.dims):
            m.insert((c, self.vector(c)))
        params.setRelinearizeThreshold(m)
