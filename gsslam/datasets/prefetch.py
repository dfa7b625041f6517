"""Read frames ahead in a background thread (image decoding overlaps tracking).

PNG/JPEG decoding costs ~10 ms per 640x480 RGB-D frame, a fifth of a 20 FPS budget. OpenCV's
decoders release the GIL, so one reader thread decodes the next frames on the second core while
the pipeline works on the current one. Frames come out in index order, exactly as ``ds[i]``
would give them (one reader, a FIFO queue): the run stays deterministic. The queue is bounded
(``depth`` frames), an exception in the reader is raised in the consumer at the frame where it
happened, and :meth:`FramePrefetcher.close` (or leaving the ``with`` block, or breaking out of the
loop) stops and joins the thread.

:class:`PrefetchedDataset` wraps a dataset so that code reading ``ds[0], ds[1], ...`` in order
(e.g. :func:`gsslam.run.sequence.run_dataset`) gets prefetched frames without any change.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
import weakref
from collections.abc import Iterator, Sequence
from typing import Any

from gsslam.datasets.base import Dataset, DatasetError
from gsslam.types import Frame

log = logging.getLogger(__name__)

_DONE = object()


class FramePrefetcher:
    """Iterate ``ds[i]`` for ``i`` in ``indices`` with up to ``depth`` frames decoded ahead."""

    def __init__(self, ds: Dataset, indices: Sequence[int] | None = None, depth: int = 4) -> None:
        if depth < 1:
            raise DatasetError(f"prefetch depth must be >= 1, got {depth}")
        self.ds = ds
        self.indices = list(range(len(ds)) if indices is None else indices)
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.wait_s = 0.0  # time the consumer spent waiting for the reader (not hidden decoding)

    def _read(self) -> None:
        try:
            for i in self.indices:
                if self._stop.is_set():
                    return
                item = self.ds[i]
                while not self._put(item):
                    if self._stop.is_set():
                        return
        except BaseException as e:  # noqa: BLE001 - handed to the consumer, raised there
            self._put_final(e)
            return
        self._put_final(_DONE)

    def _put(self, item: object) -> bool:
        try:
            self._queue.put(item, timeout=0.1)
            return True
        except queue.Full:
            return False

    def _put_final(self, item: object) -> None:
        while not self._stop.is_set() and not self._put(item):
            pass

    def __iter__(self) -> Iterator[Frame]:
        if self._thread is not None:
            raise DatasetError("a FramePrefetcher can be iterated once")
        self._thread = threading.Thread(target=self._read, name="gsslam-prefetch", daemon=True)
        self._thread.start()
        try:
            while True:
                t = time.perf_counter()
                item = self._queue.get()
                self.wait_s += time.perf_counter() - t
                if item is _DONE:
                    return
                if isinstance(item, BaseException):
                    raise item
                yield item
        finally:
            self.close()

    def close(self) -> None:
        """Stop the reader and wait for it (idempotent)."""
        self._stop.set()
        if self._thread is not None and self._thread.is_alive():
            while True:  # unblock a reader waiting on a full queue
                try:
                    self._queue.get_nowait()
                except queue.Empty:
                    break
            self._thread.join(timeout=10.0)
            if self._thread.is_alive():
                log.warning("frame prefetch thread did not stop within 10 s")

    def __enter__(self) -> FramePrefetcher:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class PrefetchedDataset:
    """``ds`` with in-order reads served by a :class:`FramePrefetcher`; other reads go to ``ds``.

    Reading ``ds[i]`` right after ``ds[i - 1]`` takes the next prefetched frame; the first read,
    or a read that skips ahead, (re)starts prefetching at ``i``; a read of an earlier frame is
    served directly. Call :meth:`close` (or use ``with``) to stop the reader thread early; it is
    also stopped when this object is garbage collected.
    """

    def __init__(self, ds: Dataset, depth: int = 4, stop: int | None = None) -> None:
        self.ds = ds
        self.depth = depth
        self.stop = len(ds) if stop is None else min(stop, len(ds))
        self._prefetcher: FramePrefetcher | None = None
        self._iter: Iterator[Frame] | None = None
        self._next = -1
        self._finalizer: weakref.finalize | None = None

    def __len__(self) -> int:
        return len(self.ds)

    def __getattr__(self, name: str) -> Any:  # name, intrinsics, has_depth, ... of the wrapped dataset
        if name == "ds":
            raise AttributeError(name)
        return getattr(self.ds, name)

    def timestamps(self) -> list[float]:
        return self.ds.timestamps()

    def ground_truth(self):
        return self.ds.ground_truth()

    @property
    def wait_s(self) -> float:
        """Seconds the consumer waited for frames from the current reader."""
        return 0.0 if self._prefetcher is None else self._prefetcher.wait_s

    def __getitem__(self, i: int) -> Frame:
        if i < 0 or i >= len(self.ds):
            return self.ds[i]  # the dataset's own error
        if i != self._next or self._iter is None:
            if i < self._next and self._iter is not None:
                return self.ds[i]  # an earlier frame: keep prefetching ahead
            self._restart(i)
        self._next = i + 1
        try:
            return next(self._iter)
        except StopIteration:  # past ``stop``: plain read
            self._iter = None
            return self.ds[i]

    def _restart(self, start: int) -> None:
        self.close()
        self._prefetcher = FramePrefetcher(self.ds, range(start, max(start + 1, self.stop)), self.depth)
        self._iter = iter(self._prefetcher)
        self._finalizer = weakref.finalize(self, self._prefetcher.close)

    def close(self) -> None:
        """Stop the reader thread (idempotent)."""
        if self._finalizer is not None:
            self._finalizer()
            self._finalizer = None
        self._iter = None

    def __enter__(self) -> PrefetchedDataset:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
