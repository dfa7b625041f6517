"""Chains of submaps, the pipeline's keyframe records and its tracking events.

A chain is a run of consecutive submaps linked through shared keyframes and optimised in one graph
(:class:`gsslam.graph.submap_graph.SubmapGraph`). Tracking loss closes a chain; the next one starts
at the current frame, placed in the output world at the last tracked pose (a guess: ``in_world`` is
False) until re-localization against an earlier chain places it for real
(:meth:`gsslam.slam.loop_stage.LoopStage.relocalize`): a rigid ``T_world_chain`` for RGB-D, a Sim(3)
one for mono (the new chain has its own scale; :mod:`gsslam.loop.chain_sim3`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gsslam.geometry import compose_rigid, sim3_scale
from gsslam.types import SubmapEncoding


@dataclass
class Event:
    frame_index: int
    kind: str  # "blank" | "flow" | "pnp" | "new_chain" | "encoder" | ...
    detail: str = ""


@dataclass
class ChainKeyframe:
    """Where a keyframe's geometry lives: the submap whose point map gives its depth."""

    chain: int
    submap: int  # the submap whose point map gives this keyframe's depth
    position: int  # index inside that submap's frame_indices
    depth: np.ndarray  # [h, w] point-map depth (submap units)


@dataclass
class Chain:
    """Consecutive submaps linked through shared keyframes, optimised in one graph."""

    graph: object
    T_world_chain: np.ndarray  # [4, 4] where the chain's origin sits in the output world (Sim(3) in mono)
    encodings: list[SubmapEncoding] = field(default_factory=list)
    failed: bool = False  # an update threw: no further optimisation of this graph
    in_world: bool = False  # T_world_chain is verified (the first chain, or re-localized against one)
    # keyframe -> rigid T_chain_cam [4, 4] from the end-of-run keyframe refinement (graph.keyframe_refine);
    # when set, these are the chain's keyframe poses (gsslam.slam.poses)
    refined_poses: dict[int, np.ndarray] | None = None

    def keyframe_pose(self, index: int) -> np.ndarray:  # [4, 4] rigid, chain frame
        """A keyframe's pose in this chain: the refined one when the chain has one, else the graph's."""
        if self.refined_poses is not None and index in self.refined_poses:
            return self.refined_poses[index]
        return self.graph.keyframe_pose(index)

    @property
    def scale(self) -> float:
        """World units per chain unit (1 unless a mono chain was re-joined with a Sim(3))."""
        return sim3_scale(self.T_world_chain)

    def world_pose(self, T_chain_cam: np.ndarray) -> np.ndarray:  # [4, 4] -> [4, 4] rigid
        """A camera pose of this chain's graph as a rigid ``T_world_cam`` in the output world."""
        return compose_rigid(self.T_world_chain, T_chain_cam)


def keyframe_confidence(chains: list[Chain], kf: ChainKeyframe) -> np.ndarray | None:  # -> [h, w]
    """The confidence of a keyframe's depth, from the submap that made it (None if that is gone).

    The mono encoder's confidence is the triangulation parallax (:mod:`gsslam.frontend.mono_encoder`):
    handed on with the keyframe's depth when it is the next submap's shared frame, it says which of
    those depths may hold the next submap's scale.
    """
    encs = chains[kf.chain].encodings if 0 <= kf.chain < len(chains) else []
    return encs[kf.submap].confidence[kf.position] if kf.submap < len(encs) else None


def pack_submap(enc: SubmapEncoding, keyframes: dict[int, ChainKeyframe], added: list[int]) -> None:
    """Keep a submap that all stages have seen compact (:meth:`SubmapEncoding.pack`, exact).

    The keyframes it gave a depth to then share that depth with it instead of holding a copy: a run's
    memory grows by what one keyframe keeps (docs/pipeline.md, "Memory").
    """
    if not enc.pack():
        return
    for idx in added:
        kf = keyframes[idx]
        kf.depth = enc.depths[kf.position]  # [h, w] contiguous, the same values


def stored_nbytes(chains: list[Chain], keyframes: dict[int, ChainKeyframe]) -> int:
    """Bytes held by the submaps' point maps and confidences and by the keyframe depths.

    A keyframe depth that is a view of its submap's packed depths adds nothing; what a run keeps per
    keyframe is this number's growth (tests/slam/test_memory.py).
    """
    total = sum(enc.nbytes for chain in chains for enc in chain.encodings)
    return total + sum(kf.depth.nbytes for kf in keyframes.values() if kf.depth.base is None)
