"""The SLAM pipeline: SING3R submaps + GaussianFlow correspondences on one GTSAM graph.

Per frame (:meth:`Pipeline.process`):

1. **Track** the frame against the latest keyframe with one dense flow (``frontend.tracking``); blank
   frames, failed flow and failed PnP are tracking-loss events.
2. **Keyframe?** by flow magnitude (``frontend.keyframes``). A non-keyframe keeps its flow matches
   to the keyframe; its pose is PnP against the keyframe's depth (sensor depth for RGB-D, the
   submap's point map for mono) composed with the keyframe's optimised pose.
3. Every K new keyframes: **encode a submap** (``frontend`` encoder; frame 0 is the previous
   submap's last keyframe with its refined depth), **add it to the graph** (submap alignment,
   scale drift, adjacency points), add **flow correspondences** between each new keyframe and
   its predecessors in the previous submap (:mod:`gsslam.slam.cross_flow`), run one **iSAM2 update**,
   close loops (:mod:`gsslam.slam.loop_stage`) and feed the Gaussian map (:mod:`gsslam.slam.map_stage`);
   these stages of one submap are :mod:`gsslam.slam.submap_step`.
4. At the end: encode the tail (fewer than K keyframes), **batch refinement**, poses for all frames.

Tracking loss for ``cfg.pipeline.max_lost_frames`` frames in a row closes the current chain of
submaps and starts a new one at the current frame (its own graph; its world placement is the
last tracked pose). A time gap longer than ``cfg.pipeline.max_time_gap_s`` is a ``gap`` event; a
monocular run also starts a new chain there (it cannot bridge the gap), an RGB-D run lets tracking
decide. A new chain is re-joined to an earlier one when re-localization against it is verified
(:meth:`gsslam.slam.loop_stage.LoopStage.relocalize`; until then the runner reports ATE per chain).
Outputs are written by :mod:`gsslam.run` (the pipeline writes no files).
"""

from __future__ import annotations

import dataclasses
import logging
import time

import cv2
import numpy as np

from gsslam.config import Config
from gsslam.errors import GsslamError
from gsslam.frontend.rgbd_tracking import MotionPrior
from gsslam.frontend.tracking import (
    FrameMatches,
    FrameTracker,
    is_blank,
)
from gsslam.slam import poses, submap_step
from gsslam.slam.chains import Chain, ChainKeyframe, Event, pack_submap
from gsslam.slam.cross_flow import CrossFlowFeed
from gsslam.slam.loop_stage import LoopStage
from gsslam.slam.plugins import call_plugins
from gsslam.slam.poses import pose_now, relative_rgbd, tracked_pose
from gsslam.types import CameraIntrinsics, Frame, StageProgress

log = logging.getLogger(__name__)


class PipelineError(GsslamError):
    """The pipeline was fed inconsistent frames (e.g. changing image size)."""


class Pipeline:
    """Feeds frames through tracking, keyframes, submap encoding and the graph."""

    def __init__(self, cfg: Config, intrinsics: CameraIntrinsics) -> None:
        from gsslam.frontend.encoder import make_encoder
        from gsslam.frontend.flow import make_flow_estimator
        from gsslam.frontend.keyframes import KeyframeSelector

        self.cfg = cfg
        self.monocular = cfg.mode == "mono"
        self.intrinsics = intrinsics
        self.flow = make_flow_estimator(cfg.flow)
        self.selector = KeyframeSelector(cfg.keyframes)
        self.encoder = make_encoder(cfg.mode, cfg.encoder, self.flow)
        pc = cfg.pipeline
        self.tracker = FrameTracker(
            self.flow, pc.track_points, pc.min_photo_consistency, pc.blank_std, use_depth=not self.monocular
        )
        self.rng = np.random.default_rng(cfg.seed)
        cv2.setRNGSeed(cfg.seed)  # RANSAC inside OpenCV: the same run gives the same trajectory
        # (reseeded per frame in process() and at close_chain(): a run resumed from a checkpoint
        # needs no OpenCV RNG state, see gsslam.run.checkpoint)
        self.chains: list[Chain] = []
        self.events: list[Event] = []
        self.timestamps: dict[int, float] = {}
        self.keyframes: dict[int, ChainKeyframe] = {}
        self.keyframe_order: list[int] = []
        self.pending: list[tuple[FrameMatches, int]] = []  # (matches to ref keyframe, chain id), mono
        self.relative: dict[int, tuple[int, np.ndarray]] = {}  # frame -> (ref keyframe, T_ref_cur), solved
        self.keyframe_relative: dict[int, tuple[int, np.ndarray]] = {}  # RGB-D keyframe -> (prev kf, T)
        self.window: list[Frame] = []  # keyframes of the submap being built; [0] is shared
        self.prev_frames: list[Frame] = []  # keyframes of the last encoded submap
        self.frames_since_kf = 0
        self.lost = 0
        self.last_good = None
        self.last_pose: np.ndarray = np.eye(4)
        self.motion = MotionPrior()  # the last two posed frames: RGB-D tracking's constant-velocity start
        self.n_icp_tracked = 0  # RGB-D frames tracked by ICP after their PnP was refused
        self.online_poses: dict[int, np.ndarray] = {}  # frame -> pose returned by process (as it arrived)
        self.n_frames = 0
        self.n_pose_outliers = 0  # non-keyframe poses replaced by interpolation (frame_poses)
        self.last_good: Frame | None = None  # last non-keyframe tracked successfully
        self.cross_flow = CrossFlowFeed(cfg, intrinsics, self.flow, self.rng)
        self.map_stage = None  # gsslam.slam.map_stage.MapStage when cfg.mapper.enabled
        if cfg.mapper.enabled:
            from gsslam.slam.map_stage import MapStage  # torch is imported only when the map is on

            self.map_stage = MapStage(cfg.mapper, intrinsics, monocular=cfg.mode == "mono")
        self.loop_stage = LoopStage(cfg.loop, cfg.mode, cfg.seed)
        self.stage_seconds = {"loops": 0.0, "map": 0.0}  # wall time inside the frame loop, by stage
        self.plugins: list = []  # gsslam.slam.plugins.Plugin: user factors into the running graph

    def add_plugin(self, plugin) -> None:
        """Call ``plugin`` (a :class:`gsslam.slam.plugins.Plugin`) on new keyframes, submaps and the end."""
        self.plugins.append(plugin)

    @property
    def n_flow_factors(self) -> int:
        """Flow factors added to the graphs so far (:class:`~gsslam.slam.cross_flow.CrossFlowFeed`)."""
        return self.cross_flow.n_factors

    # ---- per frame ---------------------------------------------------------------------------

    def process(self, frame: Frame, retry: bool = False) -> np.ndarray | None:
        """Feed one frame; returns its current pose estimate ``T_world_cam`` [4, 4] (None if it has none).

        The pose is the frame's tracked pose relative to its keyframe composed with that keyframe's
        current (optimised, where the graph has it) pose, so it is available from the second frame on
        in RGB-D; in mono once the keyframe has a point map (its first submap). The refined trajectory
        of :meth:`frame_poses` after :meth:`finish` stays the better one.
        """
        if (frame.intrinsics.width, frame.intrinsics.height) != (
            self.intrinsics.width,
            self.intrinsics.height,
        ):
            raise PipelineError(f"frame {frame.index} has another image size than the sequence")
        self.n_frames += 0 if retry else 1
        if not retry:
            cv2.setRNGSeed(self.cfg.seed + frame.index)
        if self.monocular and frame.depth is not None:
            frame = dataclasses.replace(frame, depth=None)  # a monocular run never sees sensor depth
        gap = self._time_gap(frame) if not retry else None
        self.timestamps[frame.index] = frame.timestamp
        if gap is not None:
            self.events.append(Event(frame.index, "gap", f"{gap:.2f} s without frames before this one"))
            log.warning("frame %d: %.2f s without frames before it", frame.index, gap)
            if self.monocular and self.window:  # mono cannot bridge a gap: its scale and motion are lost
                self.close_chain()
                self.events.append(Event(frame.index, "new_chain", "after a time gap"))
                self._start_chain(frame)
                return
        if not self.window:
            self._start_chain(frame)
            return self._remember(frame.index, self.online_poses.get(frame.index))
        flow, matches, status = self.tracker.track(frame)
        T_ref_cur = None
        if status.ok and not self.monocular:  # PnP, or ICP where PnP is refused (frontend/rgbd_tracking.py)
            # ICP only where a promoted keyframe cannot help (pipeline.track_icp_promote_first): the
            # retry against it, or no tracked frame to promote
            last_resort = retry or self.last_good is None or not self.cfg.pipeline.track_icp_promote_first
            track = relative_rgbd(self, frame, matches, frame_depth(self.tracker.ref), fallback=last_resort)
            T_ref_cur = track.T_ref_cur
            if T_ref_cur is None:
                status.ok, status.reason = False, "pnp"
            elif track.source == "icp":
                self.n_icp_tracked += 1
        if not status.ok and status.reason != "blank" and self.last_good is not None and not retry:
            # The keyframe is too far behind: promote the last tracked frame and try again.
            self._promote(self.last_good)
            return self.process(frame, retry=True)
        if not status.ok:
            self._tracking_failure(frame, status.reason)
            return self.online_poses.get(frame.index)  # a new chain's origin, or None
        self.lost = 0
        self.frames_since_kf += 1
        pose = self._remember(frame.index, tracked_pose(self, matches, T_ref_cur))
        if self.selector.is_keyframe(flow, self.frames_since_kf):
            if T_ref_cur is not None:  # its own track (poses.blend_between)
                self.keyframe_relative[frame.index] = (matches.ref_index, T_ref_cur)
            self._add_keyframe(frame)
            if frame.index in self.keyframes:  # its submap was just encoded: the graph's pose
                pose = self._remember(frame.index, pose_now(self, frame.index))
            return pose
        if self.monocular:
            self.pending.append((matches, len(self.chains) - 1))
        else:
            self.relative[frame.index] = (matches.ref_index, T_ref_cur)
        self.last_good = frame
        return pose

    # ---- online poses ------------------------------------------------------------------------

    def _remember(self, index: int, pose: np.ndarray | None) -> np.ndarray | None:
        if pose is not None:
            self.online_poses[index] = pose
            self.last_pose = pose
            self.motion.observe(index, pose)
        return None if pose is None else pose.copy()

    def _time_gap(self, frame: Frame) -> float | None:
        """Seconds since the previous frame when more than ``pipeline.max_time_gap_s``, else None."""
        if not self.timestamps:
            return None
        dt = frame.timestamp - max(self.timestamps.values())
        return dt if dt > self.cfg.pipeline.max_time_gap_s else None

    def _tracking_failure(self, frame: Frame, reason: str) -> None:
        self.events.append(Event(frame.index, reason, f"tracking failed ({reason})"))
        log.warning("frame %d: tracking failed (%s)", frame.index, reason)
        if reason == "blank":
            return  # the scene comes back where it left: keep the chain
        self.lost += 1
        if self.lost >= self.cfg.pipeline.max_lost_frames:
            self.close_chain()
            self.events.append(Event(frame.index, "new_chain", f"after {self.lost} lost frames"))
            self._start_chain(frame)

    def _start_chain(self, frame: Frame) -> None:
        if is_blank(frame, self.cfg.pipeline.blank_std):
            self.events.append(Event(frame.index, "blank", "no chain starts on a blank frame"))
            return
        from gsslam.graph.submap_graph import SubmapGraph

        T = self.current_pose_estimate()
        self.chains.append(Chain(SubmapGraph(self.cfg.graph, self.monocular), T, in_world=not self.chains))
        self.online_poses[frame.index] = T.copy()
        self.motion.reset()
        self.window = [frame]
        self.prev_frames = []
        self.keyframe_order.append(frame.index)
        self.tracker.set_reference(frame)
        self.frames_since_kf = 0
        self.lost = 0
        self.last_good = None

    def _promote(self, frame: Frame) -> None:
        """Make an already tracked non-keyframe a keyframe (its tracked pose is kept as a keyframe's)."""
        rel = self.relative.pop(frame.index, None)
        if rel is not None:
            self.keyframe_relative[frame.index] = rel
        self.pending = [(m, c) for m, c in self.pending if m.cur_index != frame.index]
        self.events.append(Event(frame.index, "promoted", "keyframe inserted after a tracking failure"))
        self._add_keyframe(frame)

    def _add_keyframe(self, frame: Frame) -> None:
        self.last_good = None
        self.window.append(frame)
        self.keyframe_order.append(frame.index)
        self.tracker.set_reference(frame)
        self.frames_since_kf = 0
        if len(self.window) == self.cfg.encoder.submap_size + 1:
            self._encode_window()

    # ---- submaps -----------------------------------------------------------------------------

    def _encode_window(self) -> None:
        """The window as a submap through the graph, loops and map (:mod:`gsslam.slam.submap_step`)."""
        chain, frames, cid = self.chains[-1], self.window, len(self.chains) - 1
        enc = submap_step.encode(self, chain, frames)
        if enc is None:
            self.window = [frames[-1]]
            return
        try:
            new = submap_step.add_to_graph(self, chain, cid, enc, frames)
        except GsslamError as e:
            # The graph cannot take this submap (e.g. an ill-posed system): the chain keeps what it had
            # (rolled back) and a new chain starts at this submap's last keyframe.
            self.events.append(Event(frames[-1].index, "graph", str(e)))
            log.warning("graph update failed, starting a new chain: %s", e)
            self.window = []
            self._start_chain(frames[-1])
            self.events.append(Event(frames[-1].index, "new_chain", "after a graph failure"))
            return
        self.last_pose = new.T_world_last
        if self.map_stage is not None:
            t0 = time.perf_counter()
            submap_step.map_submap(self, chain, cid, enc, frames, new)
            self.stage_seconds["map"] += time.perf_counter() - t0
        pack_submap(enc, self.keyframes, new.added)
        self.prev_frames = frames
        self.window = [frames[-1]]

    def close_chain(self) -> None:
        """Encode the keyframes still waiting for a submap (the tail); the chain takes no more submaps.

        :meth:`finish` calls it; a runner calls it first when it wants the poses before the batch
        refinement. Calling it twice does nothing the second time.
        """
        if len(self.window) > 1:
            cv2.setRNGSeed(self.cfg.seed + self.window[-1].index)
            self._encode_window()
        self.window = []

    def finish(self, run_seconds: float = 0.0, progress: StageProgress | None = None) -> None:
        """Encode the tail, batch-refine every chain's graph, run the map's final pass.

        ``progress(stage, done, total)`` reports "batch refinement" (per chain) and "final pass" (per
        step); ``run_seconds`` is the run's wall time so far (bounds the final pass when
        ``mapper.final_max_share`` is set).
        """
        self.close_chain()
        if self.plugins:
            from gsslam.graph.backend import RejectedError

            for cid, chain in enumerate(self.chains):
                if chain.encodings and not chain.failed:
                    call_plugins(self.plugins, chain, cid, "end", [{}], self.timestamps, self.events)
                    try:
                        chain.graph.update()
                    except RejectedError as e:
                        self.events.append(Event(-1, "rejected", str(e)))
        t0 = time.perf_counter()
        if self.cfg.graph.final_batch_refinement:
            todo = [c for c in self.chains if c.encodings and not c.failed]
            log.info("batch refinement of %d chain(s)", len(todo))
            for k, chain in enumerate(todo):
                if progress is not None:
                    progress("batch refinement", k, len(todo))
                try:
                    chain.graph.refine_batch()
                except GsslamError as e:
                    self.events.append(Event(-1, "graph", f"batch refinement failed: {e}"))
            if progress is not None:
                progress("batch refinement", len(todo), len(todo))
        self.stage_seconds["batch"] = time.perf_counter() - t0
        if self.cfg.graph.keyframe_refine:
            from gsslam.slam.keyframe_refine import refine_chains

            t0 = time.perf_counter()
            self.events.extend(refine_chains(self.chains, self.cfg.graph, self.monocular))
            self.stage_seconds["keyframe refine"] = time.perf_counter() - t0
        if self.map_stage is not None:
            t0 = time.perf_counter()
            try:
                self.map_stage.finalize(self.chains, run_seconds=run_seconds, progress=progress)
            except GsslamError as e:
                self.events.append(Event(-1, "mapper", f"final map refinement failed: {e}"))
            self.stage_seconds["final pass"] = time.perf_counter() - t0

    # ---- poses -------------------------------------------------------------------------------

    def keyframe_poses(self) -> dict[int, np.ndarray]:
        """``T_world_cam`` [4, 4] of every keyframe the graphs know (current estimates)."""
        return poses.keyframe_poses(self)

    def frame_poses(self) -> dict[int, np.ndarray]:
        """``T_world_cam`` of every frame that has one: keyframes, then non-keyframes via their keyframe
        (:func:`gsslam.slam.poses.frame_poses`)."""
        out, n_outliers = poses.frame_poses(self)
        if n_outliers is not None:
            self.n_pose_outliers = n_outliers
        return out

    def frame_chains(self) -> dict[int, int]:
        """The chain of every frame that can have a pose: its keyframe's chain (or the tracked chain)."""
        return poses.frame_chains(self)

    def current_pose_estimate(self) -> np.ndarray:
        """Best guess of the latest camera pose: the last pose :meth:`process` returned (or the latest
        submap's last keyframe); a new chain is placed there."""
        return self.last_pose.copy()


def frame_depth(frame: Frame | None) -> np.ndarray:
    if frame is None or frame.depth is None:
        raise PipelineError("RGB-D mode needs depth images; use --mode mono for this dataset")
    return frame.depth
