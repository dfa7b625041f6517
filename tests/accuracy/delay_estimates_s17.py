"""Session 17's delay estimate alone (the whole image's rotations): ``delay_estimates_s18.py --bands 1``.
Not a test: a measuring tool (docs/results.md, "The colour-depth delay estimated from the hand-eye pairs,
session 17"); the same arguments as tests/accuracy/delay_estimates_s18.py.

    PYTHONPATH=. python3 tests/accuracy/delay_estimates_s17.py ROW [ROW ...] [--delays-ms ...] [--starts 0,200]
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

if __name__ == "__main__":
    sys.argv = [sys.argv[0], "--bands", "1", *sys.argv[1:]]
    runpy.run_path(str(Path(__file__).with_name("delay_estimates_s18.py")), run_name="__main__")
