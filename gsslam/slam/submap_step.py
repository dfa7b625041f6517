"""One submap through the stages (step 3 of :mod:`gsslam.slam.pipeline`).

A full window of keyframes (``[0]`` is shared with the previous submap) is **encoded** (the shared frame
with the depth of the submap it was made in, or the map's rendered depth with
``mapper.shared_depth_feedback``; a mono window may hold its scale against the world's depth,
:mod:`gsslam.slam.world_depth`), **added to its chain's graph** with the flow factors of
:mod:`gsslam.slam.cross_flow` and the plugins' factors (one iSAM2 update each), checked for **loops**
(:mod:`gsslam.slam.loop_stage`), a chain not yet in the world is **re-localized**, and the submap is
**fed to the Gaussian map** (:mod:`gsslam.slam.map_stage`, registrations and depth priors back to the graph).

A stage that fails is an event; what follows is the pipeline's choice (a graph failure closes the chain
and starts a new one). ``p`` is a :class:`gsslam.slam.pipeline.Pipeline`; these functions read its public
state (``cfg``, ``monocular``, ``encoder``, ``chains``, ``keyframes``, ``prev_frames``, ``cross_flow``,
``loop_stage``, ``map_stage``, ``plugins``, ``timestamps``), add to its records (``keyframes``,
``events``, ``stage_seconds``) and assign none of its attributes.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from gsslam.errors import GsslamError
from gsslam.slam.chains import Chain, ChainKeyframe, Event, keyframe_confidence
from gsslam.slam.plugins import call_plugins
from gsslam.slam.world_depth import encode_with_world_depth
from gsslam.types import Frame, SubmapEncoding

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class NewSubmap:
    """A submap the chain's graph took (:func:`add_to_graph`)."""

    sid: int  # its index in the chain's graph
    added: list[int]  # keyframes whose depth it made (a shared frame keeps the earlier submap's)
    flows: list  # the cross-flow feed's flows, kept for the map stage (empty without a map)
    T_world_last: np.ndarray  # [4, 4] the window's last keyframe after the graph update and loops


def encode(p, chain: Chain, frames: list[Frame]) -> SubmapEncoding | None:
    """The window ``frames`` as a submap (None: the encoder failed, recorded as an ``encoder`` event)."""
    shared_depth = shared_conf = None
    if chain.encodings and frames[0].index in p.keyframes:
        shared_depth = p.keyframes[frames[0].index].depth
        shared_conf = keyframe_confidence(p.chains, p.keyframes[frames[0].index])
        if p.map_stage is not None and p.cfg.mapper.shared_depth_feedback:
            shared_depth = p.map_stage.shared_depth(p.chains, frames[0].index, shared_depth)
    enc_cfg = p.cfg.encoder
    try:
        if p.monocular and enc_cfg.mono_world_depth and shared_depth is not None:  # a turn may exhaust it
            return encode_with_world_depth(
                p.encoder, frames, chain, p.chains, p.keyframes, shared_depth, shared_conf,
                enc_cfg.min_inliers, enc_cfg.mono_world_depth_unlinked,
            )  # fmt: skip
        return p.encoder.encode(frames, shared_depth=shared_depth, shared_confidence=shared_conf)
    except GsslamError as e:
        p.events.append(Event(frames[-1].index, "encoder", str(e)))
        log.warning("submap encoding failed: %s", e)
        return None


def add_to_graph(p, chain: Chain, cid: int, enc: SubmapEncoding, frames: list[Frame]) -> NewSubmap:
    """Submap ``enc`` into chain ``cid``'s graph, then plugins, loops and re-localization.

    Raises :class:`GsslamError` when the graph cannot take it (e.g. an ill-posed system), after
    rolling back: its keyframes and encoding are removed and the chain is marked failed.
    """
    added = []
    try:
        sid = chain.graph.add_submap(enc)
        chain.encodings.append(enc)
        for pos, idx in enumerate(enc.frame_indices):
            if pos == 0 and idx in p.keyframes:
                continue  # the shared frame keeps the depth of the submap it was made in
            p.keyframes[idx] = ChainKeyframe(cid, sid, pos, enc.depths[pos].astype(np.float32))
            added.append(idx)
        flows = p.cross_flow.add(chain, p.chains, p.keyframes, p.prev_frames, frames, p.map_stage is not None)
        update_graph(chain, sid, frames[-1].index, p.events)
        if p.plugins:
            last = frames[-1].index
            for kind, calls in (("keyframe", [dict(frame_index=i) for i in added]),
                                ("submap", [dict(submap=sid, frame_index=last)])):  # fmt: skip
                call_plugins(p.plugins, chain, cid, kind, calls, p.timestamps, p.events)
            update_graph(chain, sid, frames[-1].index, p.events)
        t0 = time.perf_counter()
        p.loop_stage.after_submap(chain, cid, sid, enc, frames)
        p.stage_seconds["loops"] += time.perf_counter() - t0
        relocalize(p, chain, cid, sid, frames[-1].index)
        return NewSubmap(sid, added, flows, chain.world_pose(chain.graph.keyframe_pose(frames[-1].index)))
    except GsslamError:
        for idx in added:
            p.keyframes.pop(idx, None)
        if chain.encodings and chain.encodings[-1] is enc:
            chain.encodings.pop()
        chain.failed = True
        raise


def update_graph(chain: Chain, sid: int, frame_index: int, events: list[Event]) -> None:
    """One iSAM2 update; factors the backend rejected (and rolled back) are reported as events.

    Raises only when the new submap itself was rejected (then the pipeline starts a new chain).
    """
    from gsslam.graph.backend import RejectedError
    from gsslam.graph.keys import submap_key

    try:
        chain.graph.update()
    except RejectedError as e:
        events.append(Event(frame_index, "rejected", str(e)))
        if not chain.graph.backend.has_value(submap_key(sid)):
            raise
        log.warning("frame %d: %s", frame_index, e)


def relocalize(p, chain: Chain, cid: int, sid: int, frame_index: int) -> None:
    """A chain not yet in the world frame: try to place it against an earlier chain's submaps."""
    if chain.in_world:
        return
    T = p.loop_stage.relocalize(p.chains, cid, sid)
    if T is None:
        return
    chain.T_world_chain = T
    chain.in_world = True
    p.events.append(Event(frame_index, "rejoined", f"chain {cid} placed in the world frame"))
    if p.map_stage is not None and sid > 0:  # its earlier submaps are in the map already
        p.map_stage.follow_graph(p.chains)


def map_submap(p, chain: Chain, cid: int, enc: SubmapEncoding, frames: list[Frame], new: NewSubmap) -> None:
    """Feed the new submap to the Gaussian map; optional registrations and depth priors back to the graph."""
    try:
        p.map_stage.add_submap(p.chains, cid, new.sid, enc, frames, new.added, new.flows)
        if p.map_stage.pending and not chain.failed:
            if p.map_stage.send_registrations(chain, new.sid):
                chain.graph.update()
                p.map_stage.follow_graph(p.chains)
        if p.cfg.mapper.depth_feedback and not chain.failed:
            if p.map_stage.depth_priors(chain.graph, new.added):
                chain.graph.update()
                p.map_stage.follow_graph(p.chains)
    except GsslamError as e:
        p.events.append(Event(frames[-1].index, "mapper", str(e).splitlines()[0]))
        log.warning("mapper failed on submap %d: %s", new.sid, e)
