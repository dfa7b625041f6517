"""Signals during a run's frames: SIGINT/SIGTERM wait until the current frame is done (and checkpointed)."""

from __future__ import annotations

import logging
import signal
import threading
from typing import Any

log = logging.getLogger(__name__)


class DeferredInterrupt:
    """SIGINT/SIGTERM during the frames: the current frame is finished (and checkpointed) first.

    The first signal is recorded; :meth:`deliver_pending` (after the frame) then hands it to the
    handler that was installed before (the CLI's, Python's KeyboardInterrupt). A second signal is
    delivered at once. Only in the main thread (elsewhere signals cannot be handled).
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> DeferredInterrupt:
        if threading.current_thread() is threading.main_thread():
            for s in self.SIGNALS:
                if signal.getsignal(s) is not signal.SIG_IGN:
                    self._previous[s] = signal.signal(s, self._on_signal)
        return self

    def _on_signal(self, signum: int, frame) -> None:
        if self.signum is not None:  # the second one: now
            self._deliver(signum, frame)
        self.signum = signum
        name = signal.Signals(signum).name
        log.warning("%s: finishing the current frame (a second one interrupts at once)", name)

    def deliver_pending(self) -> None:
        if self.signum is not None:
            self._deliver(self.signum, None)

    def _deliver(self, signum: int, frame) -> None:
        previous = self._previous.get(signum)
        self._restore()
        if callable(previous):
            previous(signum, frame)
        raise KeyboardInterrupt

    def _restore(self) -> None:
        for s, h in self._previous.items():
            signal.signal(s, h)
        self._previous = {}

    def __exit__(self, *exc) -> None:
        pending = self.signum is not None and self._previous and exc[0] is None
        if pending:
            self.deliver_pending()
        self._restore()
