"""Where the error of a run on the long synthetic room comes from: one line per run folder.

    PYTHONPATH=. python tests/accuracy/synthroom_report.py RUN_DIR [RUN_DIR ...] [--segments 0,300,560,860,1000]

For each run (a folder with trajectory.tum, groundtruth.tum, metrics.json): ATE all frames (SE(3)),
keyframes, Sim(3) ATE and scale, RPE per frame, loops detected/accepted/rejected, tracking events, and
the SE(3) ATE of each segment of the room walk aligned on its own (per-segment error: local drift, not
the misplacement of whole segments; ``--segment-align sim3`` for mono runs, with each segment's scale)
and aligned with the whole run (where the run's error sits).
Not a test: a measuring tool (docs/results.md, "A long synthetic room, session 12").
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from gsslam.eval.align import align_positions
from gsslam.eval.association import associate
from gsslam.eval.rpe import compute_rpe
from gsslam.io.trajectory import read_tum


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(((a - b) ** 2).sum(1).mean()))


def report(run: Path, segments: list[int], seg_align: str = "se3") -> str:
    m = json.loads((run / "metrics.json").read_text())
    gt, est = read_tum(run / "groundtruth.tum"), read_tum(run / "trajectory.tum")
    a = associate(gt, est)
    G, E = gt.poses[a.gt_indices], est.poses[a.est_indices]  # [N, 4, 4]
    g, e = G[:, :3, 3], E[:, :3, 3]
    se3 = align_positions(g, e, "se3")
    sim3 = align_positions(g, e, "sim3")
    e_se3 = se3.apply_positions(e)
    e_sim3 = sim3.apply_positions(e)
    rpe = compute_rpe(G, E, 1)
    lc = m.get("loop_closure", {})
    idx = gt.timestamps[a.gt_indices] * 30.0  # frame index (30 Hz synthetic clock)
    seg_own, seg_whole, seg_scale = [], [], []
    for lo, hi in zip(segments[:-1], segments[1:]):
        s = (idx >= lo - 0.5) & (idx < hi - 0.5)
        if s.sum() < 3:
            seg_own.append(float("nan"))
            seg_whole.append(float("nan"))
            seg_scale.append(float("nan"))
            continue
        al = align_positions(g[s], e[s], seg_align)
        es = al.apply_positions(e[s])
        seg_scale.append(al.scale if seg_align == "sim3" else 1.0)
        seg_own.append(100 * _rmse(g[s], es))
        seg_whole.append(100 * _rmse(g[s], e_se3[s]))
    ev = m.get("events", {})
    ev_s = ", ".join(f"{k} {v}" for k, v in ev.items()) if isinstance(ev, dict) else str(ev)
    return (
        f"{run.name}: ATE {100 * _rmse(g, e_se3):.2f} cm (metrics {100 * m['ate']['rmse_m']:.2f}), "
        f"kf {100 * m.get('ate_keyframes', {}).get('rmse_m', float('nan')):.2f}, "
        f"Sim3 {100 * _rmse(g, e_sim3):.2f} cm scale {sim3.scale:.4f}, "
        f"RPE {100 * float(np.sqrt(np.mean(rpe.translation_errors ** 2))):.3f} cm "
        f"{float(np.sqrt(np.mean(rpe.rotation_errors_deg ** 2))):.3f} deg, "
        f"loops {lc.get('detected', 0)}/{lc.get('accepted', 0)}/{lc.get('rejected', 0)}; "
        f"segments {segments} own-aligned ({seg_align}) cm {['%.2f' % x for x in seg_own]} "
        + (f"scales {[f'{x:.3f}' for x in seg_scale]} " if seg_align == "sim3" else "")
        + f"whole-aligned cm {['%.2f' % x for x in seg_whole]}; kf {m.get('keyframes')} events {ev_s}"
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--segments", default="0,300,560,860,1000")
    ap.add_argument("--segment-align", default="se3", choices=["se3", "sim3"], help="sim3 for mono runs")
    a = ap.parse_args()
    segs = [int(x) for x in a.segments.split(",")]
    for r in a.runs:
        print(report(r, segs, a.segment_align), flush=True)


if __name__ == "__main__":
    main()
