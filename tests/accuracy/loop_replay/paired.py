"""Measuring tool (docs/results.md, "The graph's basin, session 10"), not a test: one row of the tracking
suite run in process as the runner runs it (map off; depth registered as run/sequence.py does), then the
final batch solved both ways from the same pre-batch graph: ``graph.batch_solve=lm`` (the pipeline's own
finish) and ``staged`` (the graph replayed into a fresh backend, re-solved, swapped in). Prints one JSON
line per solve (ATE SE(3) / Sim(3), all frames and keyframes, cm) and keeps the graph as exp.py does
(for staged.py / minima.py). Usage:
``PYTHONPATH=. python tests/accuracy/loop_replay/paired.py ROW rgbd on|off [--set k=v] [--out DIR]``."""
import argparse, json, logging, os, pickle, time
from dataclasses import replace
from pathlib import Path
import numpy as np, yaml
from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.eval.ate import compute_ate
from gsslam.factors import to_matrix
from gsslam.graph.backend import Backend
from gsslam.graph.factor_specs import build_factor
from gsslam.slam.pipeline import Pipeline
from gsslam.types import Trajectory

SUITE = Path(__file__).parents[3] / "gsslam/run/suites/tracking.yaml"


def ate(gt, ts, poses, align):
    ks = sorted(poses)
    res, _ = compute_ate(gt, Trajectory(np.array([ts[k] for k in ks]), np.stack([poses[k] for k in ks])), align=align)
    return round(100 * res.stats.rmse, 4)


def metrics(pipe, gt):
    fr, kf, ts = pipe.frame_poses(), pipe.keyframe_poses(), pipe.timestamps
    return dict(ate=ate(gt, ts, fr, "se3"), ate_kf=ate(gt, ts, kf, "se3"),
                ate_sim3=ate(gt, ts, fr, "sim3"), ate_kf_sim3=ate(gt, ts, kf, "sim3"))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("row"); ap.add_argument("mode"); ap.add_argument("loops")
    ap.add_argument("--set", action="append", default=[]); ap.add_argument("--out", default="/tmp/paired")
    ap.add_argument("--data-root", default="../shared/data"); ap.add_argument("--max-frames", type=int, default=None)
    a = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    row = next(r for r in yaml.safe_load(SUITE.read_text())["sequences"] if r["name"] == a.row)
    kw = dict(row.get("kwargs") or {})
    os.makedirs(a.out, exist_ok=True)
    if row.get("path") is None:  # a generated scene, as run/batch.py hands it to the loader
        path = Path(a.out) / f"{a.row}.yaml"; path.write_text(yaml.safe_dump(kw, sort_keys=False)); kw = {}
    else:
        path = str(Path(a.data_root) / row["path"])
    ds = open_dataset(row["dataset"], path, **kw)
    cfg = load_config(None, ["mapper.enabled=false", f"loop.enabled={'true' if a.loops == 'on' else 'false'}", *a.set], mode=a.mode)
    n = min(len(ds), row.get("frames") or len(ds), a.max_frames or len(ds))
    from gsslam.frontend.depth_registration import register_frame
    from gsslam.run.sequence import colour_registration
    reg, _ = colour_registration(ds, cfg, n)  # as the runner does
    if reg.is_identity():
        reg = None
    else:
        cfg = replace(cfg, encoder=replace(cfg.encoder, rgbd_icp=True))
    pipe = Pipeline(cfg, ds.intrinsics if reg is None else reg.colour_intrinsics(ds.intrinsics))
    t0 = time.time()
    for i in range(n):
        pipe.process(ds[i] if reg is None else register_frame(ds[i], reg))
    pipe.close_chain()
    gt = ds.ground_truth()
    logs = [c.graph.backend.replay_log() for c in pipe.chains]
    before = metrics(pipe, gt)
    pipe.finish()
    out = {"lm": metrics(pipe, gt)}
    for method in ("staged",):
        for c, lg in zip(pipe.chains, logs):
            be = Backend.from_config(replace(cfg.graph, batch_solve=method))
            be.replay(lg, build_factor)
            be.refine_batch()
            c.graph.backend = be
        out[method] = metrics(pipe, gt)
    base = dict(row=a.row, mode=a.mode, loops=a.loops, set=a.set, chains=len(pipe.chains),
                loops_in_graph=pipe.loop_stage.metrics().get("in_graph"), before_batch=before, wall=round(time.time() - t0))
    for m, v in out.items():
        line = json.dumps({**base, "batch": m, **v})
        print(line)
        with open(f"{a.out}/results.jsonl", "a") as f:
            f.write(line + "\n")
    ch = pipe.chains[0]
    st = dict(replay=[(op[0], op[1], to_matrix(op[2])) if op[0] == "value" else op for op in logs[0]],
              T_local_cam=[e.T_local_cam for e in ch.encodings], frame_indices=[list(e.frame_indices) for e in ch.encodings],
              ts=pipe.timestamps, gt=gt, loops=pipe.loop_stage.metrics(), chains=len(pipe.chains))
    with open(f"{a.out}/{a.row}_{a.mode}_{a.loops}.pkl", "wb") as f:
        pickle.dump(st, f)


main()
