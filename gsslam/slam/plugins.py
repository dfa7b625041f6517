"""Plugins: user code that adds values and factors to the graph of a running SLAM session.

Subclass :class:`Plugin` and override any of ``on_keyframe`` / ``on_submap`` / ``on_end``; pass it to
:meth:`gsslam.slam.pipeline.Pipeline.add_plugin` (or ``gsslam.Slam(..., plugins=[...])``). Each call
gets a :class:`GraphEvent` of the chain's graph:

- ``on_keyframe(event)``: a keyframe entered the graph (with its submap; ``event.frame_index``),
- ``on_submap(event)``: submap ``event.submap`` was added and optimised,
- ``on_end(event)``: the run ends, before the final batch refinement (once per chain).

What a plugin adds is sent to iSAM2 right after the call; the Gaussian map follows (the pipeline feeds
the map after the plugins, and the end-of-run map pass follows the refined graph). A factor the backend
rejects is rolled back and reported as a ``rejected`` event; the run continues. A plugin that raises
is reported as a ``plugin`` event; the run continues.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from gsslam.geometry import compose_rigid, invert_T
from gsslam.slam.chains import Event

log = logging.getLogger(__name__)


@dataclass
class GraphEvent:
    """Where a plugin is called, and the graph it may add to (``graph``: a ``SubmapGraph``)."""

    kind: str  # "keyframe" | "submap" | "end"
    chain: int
    graph: object  # gsslam.graph.submap_graph.SubmapGraph of this chain
    T_world_chain: np.ndarray  # [4, 4] where the chain's graph world sits in the output world
    frame_index: int | None = None
    submap: int | None = None
    timestamp: float | None = None

    @property
    def backend(self):
        """The chain's :class:`gsslam.graph.backend.Backend` (``add_value``, ``add_factor``, ``estimate``)."""
        return self.graph.backend

    def add_factor(self, factor, name: str | None = None) -> int:
        return self.graph.backend.add_factor(factor, name)

    def add_value(self, key: int, value) -> None:
        self.graph.backend.add_value(key, value)

    def keyframe_pose(self, frame_index: int) -> np.ndarray:
        """Current ``T_world_cam`` [4, 4] of a keyframe, in the output world."""
        return compose_rigid(self.T_world_chain, self.graph.keyframe_pose(frame_index))

    def add_keyframe_pose_prior(
        self,
        frame_index: int,
        T_world_cam: np.ndarray,  # [4, 4] rigid, output world
        rot_sigma: float = 0.01,
        trans_sigma: float = 0.01,
        name: str | None = None,
    ) -> int:
        """A prior on a keyframe's pose (expressed on its submap's variable); returns the factor handle."""
        T_chain_cam = compose_rigid(invert_T(self.T_world_chain), np.asarray(T_world_cam, float))
        return self.graph.add_keyframe_pose_prior(frame_index, T_chain_cam, rot_sigma, trans_sigma, name)

    def keep_output_world(self, G: np.ndarray) -> None:
        """The plugin moved this chain's graph world by the Sim(3) ``G`` [4, 4] (new = ``G`` old): keep
        the output world where it was, ``T_world_chain <- T_world_chain G^-1`` (in place)."""
        self.T_world_chain[...] = self.T_world_chain @ np.linalg.inv(np.asarray(G, float))


class Plugin:
    """Base class of plugins; every hook does nothing unless overridden."""

    def on_keyframe(self, event: GraphEvent) -> None:
        pass

    def on_submap(self, event: GraphEvent) -> None:
        pass

    def on_end(self, event: GraphEvent) -> None:
        pass


def call_plugins(
    plugins: list, chain, cid: int, kind: str, calls: list[dict], timestamps: dict, events: list
) -> None:
    """Call ``on_<kind>`` of every plugin with a :class:`GraphEvent` per entry of ``calls`` (its keyword
    arguments); a plugin that raises is logged and recorded in ``events``, the run goes on."""
    for kw in calls:
        idx = kw.get("frame_index")
        ev = GraphEvent(kind, cid, chain.graph, chain.T_world_chain, timestamp=timestamps.get(idx), **kw)
        for plugin in plugins:
            try:
                getattr(plugin, f"on_{kind}")(ev)
            except Exception as e:  # noqa: BLE001 - user code must not lose the run
                where = -1 if idx is None else idx
                events.append(Event(where, "plugin", f"{type(plugin).__name__}.on_{kind}: {e!r}"))
                log.warning("plugin %s.on_%s failed: %r", type(plugin).__name__, kind, e)
