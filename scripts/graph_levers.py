"""iSAM2 parameters against the median update time of ``gsslam bench graph`` (docs/results.md,
"Graph update time, session 5"). One process runs the variants in sequence; each prints one JSON line
with the CPU ms per update, the ratio of the wall median to the bench's reference workload, iSAM2's
relinearised / re-eliminated counts and the max position error. Batch LM is skipped (not measured).

    PYTHONPATH=. nice -n 19 python3 scripts/graph_levers.py imu 800 scalar,typed,typed+skip5,typed+skip10
    PYTHONPATH=. nice -n 19 python3 scripts/graph_levers.py flow 800 scalar,skip5,skip10

Variant parts, joined by ``+``: ``scalar`` (one threshold, 0.01, for every variable), ``typed`` (the
default: 0.1 for velocities and biases), ``skipN`` (``graph.relinearize_skip=N``), ``nocache``
(``cacheLinearizedFactors=False``), ``qr`` (QR factorization).
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time

import gsslam.bench.graph as bg
from gsslam.config import GraphConfig
from gsslam.graph.backend import Backend

_TWEAKS = []  # functions applied to the ISAM2Params of the next backend


class _Tweaked(Backend):
    def __init__(self, params=None, batch_max_iterations=100, thresholds=None):
        for fn in _TWEAKS:
            fn(params)
        super().__init__(params, batch_max_iterations, thresholds)

    def refine_batch(self, max_iterations=None) -> float:  # batch LM not measured here
        return 0.0


def _variant(name: str) -> GraphConfig:
    cfg = GraphConfig()
    _TWEAKS.clear()
    for part in name.split("+"):
        if part == "scalar":
            cfg = dataclasses.replace(cfg, relinearize_threshold_velocity=0.0, relinearize_threshold_bias=0.0)
        elif part == "typed":
            pass
        elif part.startswith("skip"):
            cfg = dataclasses.replace(cfg, relinearize_skip=int(part[4:]))
        elif part == "nocache":
            _TWEAKS.append(lambda p: setattr(p, "cacheLinearizedFactors", False))
        elif part == "qr":
            _TWEAKS.append(lambda p: p.setFactorization("QR"))
        else:
            raise SystemExit(f"unknown variant part {part!r}")
    return cfg


def main(argv: list[str]) -> None:
    imu, n, variants = argv[0] == "imu", int(argv[1]), argv[2].split(",")
    bg.Backend = _Tweaked
    for v in variants:
        cfg = _variant(v)
        t0 = time.time()
        r = bg.run_one(n, 1000, cfg, imu=imu)
        keys = (
            "isam2_update_cpu_ms_median",
            "isam2_update_cpu_ms_p90",
            "isam2_update_ms_median",
            "reference_ms",
            "isam2_update_median_per_reference",
            "isam2_relinearized_mean",
            "isam2_reeliminated_mean",
            "isam2_position_error_max_m",
        )
        out = {"imu": imu, "n": n, "variant": v, "wall_s": round(time.time() - t0)} | {k: r[k] for k in keys}
        print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
