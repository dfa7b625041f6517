"""What :class:`gsslam.graph.backend.Backend` raises: its errors and the record of a dropped factor/value.

:class:`BackendError` is a factor or value the backend cannot use; :class:`RejectedError` says that an
update dropped some buffered factors/values (each a :class:`Rejection`) and applied everything else.
The names stay importable from :mod:`gsslam.graph.backend`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from gsslam.errors import GsslamError

# suffix of a Rejection.cause when a whole update batch was rolled back (no single factor to blame)
BATCH_TAG = " [batch]"


class BackendError(GsslamError):
    """A factor or value the backend cannot use (unknown key, duplicate value, unknown handle)."""


@dataclass(frozen=True)
class Rejection:
    """One factor (``handle`` set) or value (``key`` set) that ``Backend.update`` dropped."""

    what: str  # e.g. "factor 'gps x23' (PriorFactorPose3 on x23)" or "value b3 (ConstantBias)"
    cause: str  # e.g. "missing key x23: it has no value"
    handle: int | None = None
    key: int | None = None


class RejectedError(BackendError):
    """``Backend.update`` dropped some buffered factors/values; every other change WAS applied.

    The graph is usable: the next update works without further action. ``rejected`` lists what was
    dropped (:class:`Rejection`).
    """

    def __init__(self, rejected: list[Rejection]):
        self.rejected = list(rejected)
        lines, seen = [], set()
        for r in self.rejected:
            if r.cause.endswith(BATCH_TAG):  # one line for a rolled-back batch
                if BATCH_TAG not in seen:
                    n = sum(r_.handle is not None and r_.cause.endswith(BATCH_TAG) for r_ in self.rejected)
                    vals = [r_.what.split()[1] for r_ in self.rejected if r_.key is not None]
                    lines.append(
                        f"the whole update ({n} factors, new values {','.join(vals) or 'none'}): "
                        f"{r.cause[: -len(BATCH_TAG)]}; no single factor of the batch is to blame"
                    )
                    seen.add(BATCH_TAG)
            elif r.key is None or not r.cause.startswith("rolled back"):
                lines.append(f"{r.what}: {r.cause}")
        super().__init__("rejected and rolled back " + "; ".join(lines))


def first_line(e: BaseException) -> str:
    """The first non-empty line of an exception message (gtsam's start with a newline), for messages."""
    lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
    text = " ".join(lines[:2]) if lines else type(e).__name__
    if not isinstance(e, RuntimeError):
        text = f"{type(e).__name__}: {text}"
    # gtsam prints the raw key integer next to the symbol name; keep the symbol only
    return re.sub(r"\s*\d{6,}\s*\(Symbol: (\w+)\)", r" \1", text)
