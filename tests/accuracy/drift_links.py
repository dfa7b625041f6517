"""Summary of drift_probe.py outputs: the spread of the submap scales, the chaining steps, rotation errors.

    python tests/accuracy/drift_links.py LOG [LOG ...]

Not a test: a measuring tool (docs/results.md, "Drift on harder sequences, session 6").
"""

import sys

import numpy as np

for f in sys.argv[1:]:
    r, rot = [], []
    for line in open(f):
        p = line.split()
        if len(p) >= 10 and p[0].isdigit() and "-" in p[1]:
            try:
                r.append(float(p[-4]))
                rot.append(float(p[-1]))
            except ValueError:
                pass
    r, rot = np.array(r), np.array(rot)
    r, rot = r[np.isfinite(r)], rot[np.isfinite(rot)]
    L = np.abs(np.diff(np.log(r)))
    ate = [x.strip() for x in open(f) if x.startswith("ATE")]
    print(
        f"{f}: submaps {len(r)}, std log enc/gt {np.std(np.log(r)):.3f}, |log link| mean {L.mean():.3f} "
        f"max {L.max():.3f}, rotation error mean {rot.mean():.2f} deg; {ate}"
    )
