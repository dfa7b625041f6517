"""Can a low-parallax window of the long synthetic room's first turn measure its poses and depth at all?

    PYTHONPATH=. python tests/accuracy/turn_windows.py [--starts 309,315,321,333,345]

For each start frame: 7 consecutive frames (the windows the pipeline makes in the turn, a keyframe per
frame) through the mono encoder with the TRUE depth of the first frame as the shared depth (full view,
the best a carried depth could be) and ``encoder.mono_turn_rotation``; prints the encoder's verdict,
``r`` (its local translations against the truth's, 1 = right) and, for frames 0 / 3 / 6, the share of
pixels the two-ray triangulation gives a depth and its median ratio to the true depth, with the
encoder's poses and with the true ones. Not a test: a measuring tool (docs/results.md, "Mono across
turns, session 13").
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

ROOM = dict(n_frames=1000, width=320, height=240, scene="furnished_room", trajectory="room_walk", seed=0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--starts", default="309,315,321,333,345")
    a = ap.parse_args(argv)
    from gsslam.config import EncoderConfig, FlowConfig
    from gsslam.datasets.base import loader
    from gsslam.frontend.encoder import make_encoder, resize_image
    from gsslam.frontend.flow import chained_flows, make_flow_estimator
    from gsslam.frontend.mono_depth import dense_depth
    from gsslam.geometry import invert_T

    ds = loader("synthetic")(None, **ROOM)
    for start in (int(s) for s in a.starts.split(",")):
        fr = [ds[i] for i in range(start, start + 7)]
        frames = [dataclasses.replace(f, depth=None) for f in fr]
        enc = make_encoder("mono", EncoderConfig(mono_turn_rotation=True), make_flow_estimator(FlowConfig()))
        e = enc.encode(frames, shared_depth=fr[0].depth)
        G = np.stack([invert_T(fr[0].T_world_cam_gt) @ f.T_world_cam_gt for f in fr])  # [7, 4, 4]
        tg, te = G[:, :3, 3], e.T_local_cam[:, :3, 3]
        nt, ne = np.linalg.norm(tg, axis=1), np.linalg.norm(te, axis=1)
        r = float((ne * nt).sum() / (nt**2).sum())
        imgs = [resize_image(f.image, e.intrinsics) for f in frames]
        fw, bw, valid = chained_flows(imgs, enc.flow, 1.0, enc.cfg.min_texture_gradient)
        out = []
        for name, T in (("encoder poses", e.T_local_cam), ("true poses", G)):
            P, _ = dense_depth(enc.flow, imgs, fw, bw, valid, T, e.intrinsics, enc.cfg)
            for i in (0, 3, 6):
                z, zt = P[i, ..., 2], fr[i].depth
                ok = np.isfinite(z) & np.isfinite(zt)
                ratio = float(np.exp(np.median(np.log(z[ok] / zt[ok])))) if ok.sum() > 30 else float("nan")
                out.append(f"{name} f{i} {ok.mean():.2f} x{ratio:.3f}")
        print(f"{start}: {e.meta['reason']}, r {r:.3f}; " + "; ".join(out), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
