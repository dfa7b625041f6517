"""How much a mono submap's local rotations depend on the encoder's random sample, per config.

    PYTHONPATH=. python tests/accuracy/mono_hypotheses_spread.py RUN_DIR --first 52 --first 133 \
        --seeds 5 --config default= --config h4=encoder.mono_two_view_hypotheses=4 [--kw key=value ...]

RUN_DIR is a finished mono run (its ``keyframes.tum`` gives the submaps, grouped as the pipeline grouped
them; ``--first F`` picks the submap whose first keyframe is dataset frame F). Every picked submap is
encoded alone, in process, with encoder seeds 0..S-1 under every ``--config NAME=k=v,k=v``; the tool
prints per submap and config the BA rotation error (deg, mean over the submap's local poses ``R_0_i``)
for each seed, their mean and range, the chosen hypothesis, and the encoder's time as a ratio to the
first config's (measured in the same process). Not a test: a measuring tool (docs/results.md, "Mono
two-view hypotheses, session 9").
"""

from __future__ import annotations

import argparse
import logging
import time

import numpy as np
import yaml

from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.frontend.flow import make_flow_estimator
from gsslam.frontend.mono_encoder import MonoEncoder
from gsslam.geometry import invert_T, so3_log


def rot_err_deg(R_est: np.ndarray, R_gt: np.ndarray) -> float:  # [3, 3] x2
    return float(np.degrees(np.linalg.norm(so3_log(R_est.T @ R_gt))))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir")
    ap.add_argument("--seq", default="../shared/data/rgbd_dataset_freiburg3_teddy")
    ap.add_argument("--dataset", default="playback")
    ap.add_argument("--kw", action="append", default=[], help="dataset kwarg key=value (value YAML)")
    ap.add_argument("--first", action="append", type=int, default=[], help="first frame of a submap")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument(
        "--config", action="append", default=[], help="NAME=key=value,key=value ('NAME=': defaults)"
    )
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    kw = {"base": "tum", "pattern": "fbf"} if a.dataset == "playback" else {}
    for s in a.kw:
        k, v = s.split("=", 1)
        kw[k] = yaml.safe_load(v)
    if a.dataset == "tum":
        kw["with_depth"] = False  # colour only (other loaders have no depth or take no such argument)
    ds = open_dataset(a.dataset, a.seq, **kw)
    ts = np.asarray(ds.timestamps())
    kf_ts = np.loadtxt(f"{a.run_dir}/keyframes.tum", comments="#", usecols=0, ndmin=1)
    kf = [int(np.argmin(np.abs(ts - t))) for t in kf_ts]
    configs = []
    for c in a.config or ["default="]:
        name, over = c.split("=", 1)
        configs.append((name, [o for o in over.split(",") if o]))
    K1 = load_config(None, [], mode="mono").encoder.submap_size
    groups = [kf[s : s + K1 + 1] for s in range(0, len(kf) - K1, K1)]
    groups = [g for g in groups if not a.first or g[0] in a.first]
    summary: dict[str, list] = {name: [] for name, _ in configs}
    times: dict[str, float] = {name: 0.0 for name, _ in configs}
    for g in groups:
        frames = [ds[i] for i in g]
        gt = [f.T_world_cam_gt for f in frames]
        R_gt = [(invert_T(gt[0]) @ x)[:3, :3] for x in gt]  # R_0_i
        for name, over in configs:
            cfg = load_config(None, ["mapper.enabled=false", *over], mode="mono")
            flow = make_flow_estimator(cfg.flow)
            errs, chosen = [], []
            for seed in range(a.seeds):
                t0 = time.perf_counter()
                e = MonoEncoder(cfg.encoder, flow, seed=seed).encode(frames)
                times[name] += time.perf_counter() - t0
                T = e.meta.get("T_i_0_ba")
                if T is None:
                    errs.append(float("nan"))
                    continue
                errs.append(float(np.mean([rot_err_deg(T[i][:3, :3].T, R_gt[i]) for i in range(1, len(g))])))
                chosen.append(f"{e.meta.get('hypothesis', 0)}/{len(e.meta.get('hypotheses', [0]))}")
            summary[name].append(errs)
            print(
                f"{g[0]:4d}-{g[-1]:<4d} {name:>10s}  "
                + " ".join(f"{x:5.2f}" for x in errs)
                + f"  mean {np.nanmean(errs):.2f} range {np.nanmax(errs) - np.nanmin(errs):.2f}"
                + f"  chosen {' '.join(chosen)}",
                flush=True,
            )
    base = times[configs[0][0]]
    for name, _ in configs:
        e = np.asarray(summary[name])
        print(
            f"{name:>10s}: mean {np.nanmean(e):.3f} deg, "
            f"mean per-submap range {np.nanmean(np.nanmax(e, 1) - np.nanmin(e, 1)):.3f}, "
            f"worst {np.nanmax(e):.2f}; encoder time x{times[name] / base:.2f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
