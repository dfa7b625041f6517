"""Resident memory of this process: now, its peak, and the peak's reset at the start of a run.

``ru_maxrss`` (and Linux's ``VmHWM``) is the process's high-water mark since it started: in a batch that
runs several sequences in one process (``gsslam batch --jobs 1``), every run after the largest would
report that run's peak. Linux lets a process reset its own mark (``/proc/self/clear_refs``, value 5,
since Linux 4.0), so :func:`reset_peak_rss` is called when a run starts and the run's metrics say whose
peak they report (``peak_rss_scope``: ``"run"`` after a reset, ``"process"`` where none is possible).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
import resource
import sys

log = logging.getLogger(__name__)

__all__ = ["HeapTrimmer", "peak_rss_mb", "reset_peak_rss", "rss_mb", "trim_heap"]


def _status_kb(field: str) -> int | None:
    """A ``kB`` field of ``/proc/self/status`` (Linux), else None."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return None


def peak_rss_mb() -> float:
    """Peak resident memory since the process started or since the last :func:`reset_peak_rss`, in MB
    (``VmHWM``; elsewhere ``getrusage``'s ``ru_maxrss``, which cannot be reset)."""
    hwm = _status_kb("VmHWM")
    if hwm is not None:
        return hwm / 1024
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1024 * 1024) if sys.platform == "darwin" else peak / 1024


def rss_mb() -> float:
    """Resident memory now, in MB (Linux ``/proc``; elsewhere the peak so far)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return peak_rss_mb()


def reset_peak_rss() -> bool:
    """Reset the process's peak resident memory to its current size; True if the system allowed it."""
    before = _status_kb("VmHWM")
    if before is None:
        return False
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError as e:
        log.debug("peak RSS not reset (%s): the run reports the process's peak", e)
        return False
    after = _status_kb("VmHWM")
    return after is not None and after <= before


_LIBC: ctypes.CDLL | None | bool = False  # False: not looked up yet; None: no malloc_trim here


def trim_heap() -> bool:
    """Hand the C heap's free pages back to the system (glibc ``malloc_trim(0)``); True if it ran.

    A run frees as much as it allocates per frame (images, flows, renders), and glibc keeps the freed
    pages of its heap resident until they are reused: at 1000 frames of teddy played fbfbfb ~200 MB of the
    process's resident memory was free heap (docs/results.md, "Memory flat in length, session 14").
    Trimming changes no allocation the run makes, only which free pages stay resident; elsewhere
    (macOS, musl) it does nothing.
    """
    global _LIBC
    if _LIBC is False:
        name = ctypes.util.find_library("c") if sys.platform.startswith("linux") else None
        try:
            _LIBC = ctypes.CDLL(name) if name else None
            if _LIBC is not None and not hasattr(_LIBC, "malloc_trim"):
                _LIBC = None
        except OSError:
            _LIBC = None
    if _LIBC is None:
        return False
    _LIBC.malloc_trim(0)
    return True


class HeapTrimmer:
    """Calls :func:`trim_heap` whenever a count (the run's submaps) has grown since the last call."""

    def __init__(self, enabled: bool, count: int = 0) -> None:
        self.enabled, self.count, self.trims = enabled, count, 0

    def after(self, count: int) -> None:
        if count > self.count:
            self.now()
        self.count = count

    def now(self) -> None:
        if self.enabled:
            self.trims += trim_heap()
