"""Cost and accuracy of the registration feedback on the teddy forward-backward-forward revisit (session 6).

    python3 scripts/registration_cost.py run MODE OUT [KEY=VALUE ...]  # one fbf run (feedback-suite
        # settings, no final pass, 1 thread): ATE, CPU s of the map stage and the registrations -> OUT.json
    python3 scripts/registration_cost.py snap MODE OUT.pt N [KEY=VALUE ...]  # the same run, stopped
        # after N registrations reached Gauss-Newton: their inputs (converged map, keyframe) -> OUT.pt
    python3 scripts/registration_cost.py compare OUT.pt [central warp ...]  # each saved registration again
        # with each mapper.registration_jacobian: CPU seconds, pose difference to the first, gate

Data: ../shared/data/rgbd_dataset_freiburg3_teddy (docs/evaluation.md). CPU seconds are process time with
one torch thread: comparable across runs on a loaded machine, unlike wall time. docs/results.md,
"Registration cost, session 6".
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

import gsslam.mapping.mapper as mapper_mod
import gsslam.mapping.registration as reg
from gsslam.config import load_config
from gsslam.mapping.state import MapState
from gsslam.run.run_metrics import evaluate_run
from gsslam.run.sequence import run_sequence
from gsslam.slam import submap_step

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "rgbd_dataset_freiburg3_teddy"
FBF = dict(base="tum", pattern="fbf", pause_every=97, pause_len=15, jump_every=151, jump_len=4, seed=0)
SUITE = ["loop.enabled=false", "mapper.max_side=120", "mapper.iterations=20",
         "mapper.final_iterations_per_keyframe=0", "mapper.num_threads=1"]  # fmt: skip


def _run(mode: str, out: str, overrides: list[str]):
    cfg = load_config(None, SUITE + overrides, mode=mode)
    return run_sequence(DATA, "playback", cfg, out, progress=False, overwrite=True, **FBF)


def cmd_run(mode: str, out: str, *overrides: str) -> None:
    cpu = {"map": 0.0, "register": 0.0, "n_register": 0}

    def timed(fn, key, count=None):
        @functools.wraps(fn)
        def w(*a, **k):
            t = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                cpu[key] += time.process_time() - t
                if count:
                    cpu[count] += 1

        return w

    submap_step.map_submap = timed(submap_step.map_submap, "map")  # the map stage, registrations included
    mapper_mod.register = timed(mapper_mod.register, "register", "n_register")
    c0 = time.process_time()
    res = _run(mode, out, list(overrides))
    row = {k: evaluate_run(Path(out)).get(k) for k in ("ate_m", "ate_kf_m", "keyframes")}
    mp = res.metrics.get("mapper") or {}
    row.update(mode=mode, overrides=list(overrides), cpu_total_s=time.process_time() - c0)
    row.update(cpu_map_s=cpu["map"], cpu_register_s=cpu["register"], registrations_tried=cpu["n_register"])
    row.update(registrations=mp.get("registration_factors"), stage_seconds=res.metrics.get("stage_seconds"))
    Path(out + ".json").write_text(json.dumps(row, indent=1))
    print(json.dumps(row))


class _Enough(Exception):
    pass


def cmd_snap(mode: str, out: str, n: str, *overrides: str) -> None:
    gauss_newton, snaps = reg.gauss_newton, []

    def record(state, kf, iterations):
        kf0 = copy.deepcopy(kf)
        res = gauss_newton(state, kf, iterations)
        keep = ("cfg", "intrinsics", "K", "strategy", "model", "backend")
        snaps.append(dict({k: getattr(state, k) for k in keep}, kf=kf0, iterations=iterations))
        if len(snaps) >= int(n):
            torch.save(snaps, out)
            raise _Enough
        return res

    reg.gauss_newton = record
    try:
        _run(mode, out + ".run", list(overrides))
    except _Enough:
        pass
    torch.save(snaps, out)


def _gated(st: MapState, kf, info, coverage, sigma) -> bool:  # the gates of registration.register
    c = st.cfg
    D = np.diag([1.0] * 3 + [kf.median_depth] * 3)
    ev = np.linalg.eigvalsh(D @ info @ D)
    cond = ev[-1] / max(ev[0], 1e-12)
    ok = coverage >= c.registration_min_coverage and sigma <= c.registration_max_residual
    return not (ok and ev[0] >= c.registration_min_information and cond <= c.registration_max_condition)


def cmd_compare(path: str, *variants: str) -> None:
    torch.set_num_threads(1)
    variants = variants or ("central", "warp")
    total = {v: [0.0, 0] for v in variants}
    for s in torch.load(path, weights_only=False):
        line, ref = [f"kf {s['kf'].index}"], None
        for v in variants:
            cfg = dataclasses.replace(s["cfg"], registration_jacobian=v)
            parts = {k: s[k] for k in ("intrinsics", "K", "strategy", "model", "backend")}
            st = MapState(cfg=cfg, device=torch.device("cpu"), densify_state={}, **parts)
            kf = copy.deepcopy(s["kf"])
            t = time.process_time()
            info, coverage, sigma = reg.gauss_newton(st, kf, s["iterations"])
            dt = time.process_time() - t
            d = kf.delta.double().numpy()
            ref = d if ref is None else ref
            kept = not _gated(st, kf, info, coverage, sigma)
            total[v][0] += dt
            total[v][1] += kept
            moved, dt_mm = 1000 * np.linalg.norm(d[:3]), 1000 * np.linalg.norm(d[:3] - ref[:3])
            d_deg = np.degrees(np.linalg.norm(d[3:] - ref[3:]))
            state = "kept" if kept else "gated"
            line.append(
                f"{v}: {dt:.2f} s {state} moved {moved:.1f} mm (vs first {dt_mm:.1f} mm {d_deg:.2f} deg)"
            )
        print(" | ".join(line), flush=True)
    for v, (t, k) in total.items():
        print(f"{v}: {t:.2f} CPU s, {k} kept")


if __name__ == "__main__":
    {"run": cmd_run, "snap": cmd_snap, "compare": cmd_compare}[sys.argv[1]](*sys.argv[2:])
