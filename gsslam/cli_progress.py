"""The progress bar of ``gsslam run``: one bar that follows the stages of a run (docs/run_folders.md)."""

from __future__ import annotations

import sys


class StageBar:
    """One tqdm bar that restarts (own total, rate and ETA) at every stage of a run."""

    def __init__(self) -> None:
        self._bar = None  # created at the first update, so that errors before the run stay one line
        self.name = "tracking"

    @property
    def bar(self):
        if self._bar is None:
            from tqdm import tqdm

            self._bar = tqdm(desc="tracking", unit="frame", file=sys.stderr, dynamic_ncols=True)
        return self._bar

    def frames(self, done: int, total: int, fps: float) -> None:
        self.bar.total = total
        self.bar.set_postfix_str(f"{fps:.1f} FPS", refresh=False)
        self.bar.update(done - self.bar.n)

    def stage(self, name: str, done: int, total: int) -> None:
        if name != self.name:
            self.name = name
            self.bar.reset(total=total)
            self.bar.set_description(name, refresh=False)
            self.bar.unit = "step" if name == "final pass" else "it"
            self.bar.set_postfix_str("", refresh=False)
        self.bar.total = total
        self.bar.update(done - self.bar.n)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
