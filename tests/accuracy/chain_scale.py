"""The mono encoder's scale chaining alone: a chain of submaps encoded as the pipeline does, scale vs GT.

    PYTHONPATH=. python tests/accuracy/chain_scale.py [--gap 2] [--submaps 20] [--kw stride=2] \
        [--set key=value]

Keyframes every ``--gap`` played frames, submaps of ``encoder.submap_size + 1`` keyframes, each encoded
with the previous submap's depth of the shared frame (as ``Pipeline._encode_window`` does, no graph).
Prints per submap the least-squares ratio of the encoder's local translations to the ground truth's
(``enc/gt``: the submap's scale as chained), its ratio to the previous submap's (``link``) and at the
end the spread of the links (log std: the random walk of the chained scale) and the drift
(last / first). Not a test: a measuring tool (docs/results.md, "Drift on harder sequences, session 6").
"""

from __future__ import annotations

import argparse
import dataclasses
import logging

import numpy as np
import yaml

from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.frontend.encoder import make_encoder
from gsslam.frontend.flow import make_flow_estimator
from gsslam.geometry import invert_T


def local_scale(enc, frames) -> float:
    G0 = frames[0].T_world_cam_gt
    num = den = 0.0
    for j, f in enumerate(frames[1:], 1):
        Tg = invert_T(G0) @ f.T_world_cam_gt
        num += np.linalg.norm(enc.T_local_cam[j][:3, 3]) * np.linalg.norm(Tg[:3, 3])
        den += np.linalg.norm(Tg[:3, 3]) ** 2
    return num / den


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seq", default="../shared/data/rgbd_dataset_freiburg3_teddy")
    ap.add_argument("--kw", action="append", default=[])
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--gap", type=int, default=2)
    ap.add_argument("--start", type=int, default=0)
    ap.add_argument("--submaps", type=int, default=20)
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    kw = {"base": "tum", "pattern": "fbfbf"}
    for s in a.kw:
        k, v = s.split("=", 1)
        kw[k] = yaml.safe_load(v)
    ds = open_dataset("playback", a.seq, **kw)
    cfg = load_config(None, a.overrides, mode="mono")
    enc_ = make_encoder("mono", cfg.encoder, make_flow_estimator(cfg.flow))
    K = cfg.encoder.submap_size
    shared, shared_conf, idx0, prev, links = None, None, a.start, None, []
    for i in range(a.submaps):
        idx = [idx0 + a.gap * j for j in range(K + 1)]
        if idx[-1] >= len(ds):
            break
        frames = [ds[j] for j in idx]
        frames = [dataclasses.replace(f, depth=None) for f in frames]
        if any(f.T_world_cam_gt is None for f in frames):
            print(f"{i}: frames {idx[0]}-{idx[-1]} lack ground truth; chain restarted")
            shared, shared_conf, prev = None, None, None
            idx0 = idx[-1]
            continue
        enc = enc_.encode(frames, shared_depth=shared, shared_confidence=shared_conf)
        r = local_scale(enc, frames)
        link = r / prev if prev else float("nan")
        if prev:
            links.append(np.log(link))
        m = enc.meta
        print(
            f"{i:3d} {idx[0]:4d}-{idx[-1]:<4d} {m.get('scale_source', ''):13s} "
            f"{m.get('reason', '')[:20]:20s} "
            f"g2 {m.get('dense_scale_correction', float('nan')):6.3f} enc/gt {r:7.4f} "
            f"link {link:6.3f} sigma {m.get('link_sigma', float('nan')):.4f}",
            flush=True,
        )
        shared, shared_conf, prev, idx0 = enc.depths[-1], enc.confidence[-1], r, idx[-1]
    if links:
        L = np.array(links)
        print(
            f"links: {len(L)}, log-link mean {L.mean():+.4f} std {L.std():.4f}, "
            f"|log| mean {np.abs(L).mean():.4f}, "
            f"drift last/first {np.exp(L.sum()):.3f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
