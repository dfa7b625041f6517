"""GaussianFlow's flow-BA feed: dense flow between keyframes of consecutive submaps into the graph.

After submap ``i`` is added to its chain's graph, every new keyframe ``b`` is matched by forward and
backward flow to up to ``pipeline.cross_flow_back`` predecessors ``a`` in the previous submap. The
forward-backward consistent pixels of ``a`` with point-map depth become
:func:`gsslam.frontend.correspondences.correspondences_from_flow` correspondences, added to the graph
as one flow-reprojection factor per pair (``SubmapGraph.add_flow``). The same checked flows supervise
the Gaussian map (GaussianFlow's flow loss), so they are returned for the map stage.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from gsslam.config import Config
from gsslam.frontend.correspondences import correspondences_from_flow
from gsslam.frontend.flow import forward_backward_mask
from gsslam.slam.chains import Chain, ChainKeyframe
from gsslam.types import CameraIntrinsics, Frame

log = logging.getLogger(__name__)

Flow = tuple[int, int, np.ndarray, np.ndarray]  # (a, b, flow [H, W, 2] a -> b, valid [H, W])


class CrossFlowFeed:
    """Adds flow factors between the keyframes of two consecutive submaps of a chain."""

    def __init__(self, cfg: Config, intrinsics: CameraIntrinsics, flow, rng: np.random.Generator) -> None:
        self.cfg = cfg
        self.intrinsics = intrinsics
        self.flow = flow
        self.rng = rng
        self.n_factors = 0  # flow factors added to the graphs so far

    def add(
        self,
        chain: Chain,
        chains: list[Chain],
        keyframes: dict[int, ChainKeyframe],
        prev_frames: list[Frame],  # keyframes of the previous submap; [-1] is shared with ``frames``
        frames: list[Frame],  # keyframes of the new submap; [0] is the shared one
        keep_flows: bool,
    ) -> list[Flow]:
        """Flow factors from each new keyframe to its predecessors; returns the flows when ``keep_flows``."""
        flows: list[Flow] = []
        if not prev_frames:
            return flows
        sequence = prev_frames + frames[1:]  # keyframes in order; prev_frames[-1] is shared
        first_new = len(prev_frames)
        back = self.cfg.pipeline.cross_flow_back
        for b in range(first_new, len(sequence)):
            for a in range(max(0, b - back), first_new):
                src, tgt = sequence[a], sequence[b]
                fw = self.flow(src.image, tgt.image)
                bw = self.flow(tgt.image, src.image)
                valid = forward_backward_mask(fw, bw, self.cfg.flow.fb_threshold_px)
                kf = keyframes[src.index]
                if not (chains[kf.chain].encodings[kf.submap].confidence[kf.position] > 0).any():
                    continue  # a zero-parallax placeholder depth (mono) is no geometry to project
                depth = cv2.resize(
                    kf.depth, (self.intrinsics.width, self.intrinsics.height), interpolation=cv2.INTER_NEAREST
                )
                corr = correspondences_from_flow(
                    src, tgt, fw, valid, depth, self.cfg.pipeline.flow_points, self.rng
                )
                if (
                    len(corr) >= 10
                    and chain.graph.add_flow(corr, self.intrinsics.K, src_submap=kf.submap) is not None
                ):
                    self.n_factors += 1
                if keep_flows:
                    flows.append((src.index, tgt.index, fw, valid))
        return flows
