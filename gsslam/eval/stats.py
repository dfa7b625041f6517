"""Summary statistics of a vector of per-pose errors (evo's set: rmse, mean, median, std, min, max, sse)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class ErrorStats:
    """Statistics of ``n`` non-negative errors; ``std`` is the population standard deviation."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    n: int

    @classmethod
    def from_errors(cls, errors: np.ndarray) -> ErrorStats:  # errors [N], N >= 1
        e = np.asarray(errors, dtype=np.float64).reshape(-1)
        if e.size == 0:
            raise ValueError("ErrorStats needs at least one error value")
        return cls(
            rmse=float(np.sqrt(np.mean(e**2))),
            mean=float(np.mean(e)),
            median=float(np.median(e)),
            std=float(np.std(e)),
            min=float(np.min(e)),
            max=float(np.max(e)),
            sse=float(np.sum(e**2)),
            n=int(e.size),
        )

    def to_dict(self) -> dict:
        return asdict(self)
