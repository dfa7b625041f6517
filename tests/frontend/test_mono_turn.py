"""Mono windows inside a turn: low parallax, the carried depth left behind (docs/frontend.md, "Turns").

In a rotation-dominated turn the shared frame's depth (carried from the last window with parallax)
covers less of each new view; PnP against it fails once the view has left it. The window must keep
its rotation then (``encoder.mono_turn_rotation``, on by default), and a window whose shared depth is only a
placeholder plane must say that its scale is a guess (``meta["shared_placeholder"]``).
"""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.config import EncoderConfig, FlowConfig
from gsslam.frontend.encoder import make_encoder
from gsslam.frontend.flow import make_flow_estimator
from gsslam.geometry import so3_log
from helpers.plane_scene import PlaneScene, pure_rotation


def _encoder(**enc):
    return make_encoder("mono", EncoderConfig(**enc), make_flow_estimator(FlowConfig()))


def _rotation_errors(enc, frames) -> np.ndarray:  # [n - 1] deg
    gt = np.stack([f.T_world_cam_gt for f in frames])
    R = [(np.linalg.inv(gt[0]) @ gt[i])[:3, :3] for i in range(1, len(frames))]
    err = [so3_log(enc.T_local_cam[i, :3, :3].T @ Ri) for i, Ri in enumerate(R, 1)]
    return np.degrees(np.linalg.norm(err, axis=1))


@pytest.fixture(scope="module")
def turn():
    """7 frames turning 3 deg each (18 deg in all) about a fixed centre; the carried depth covers only
    the 64 px strip that the turn moves out of view (as after the first windows of a turn)."""
    scene = PlaneScene(seed=0)
    frames = scene.frames(pure_rotation(7, 3.0))
    depth0 = scene.render(frames[0].T_world_cam_gt)[1]
    carried = depth0.copy()
    carried[:, 64:] = np.nan
    return frames, carried


def test_turn_keeps_its_rotation_where_the_carried_depth_is_left_behind(turn):
    frames, carried = turn
    old = _encoder(mono_turn_rotation=False).encode(frames, shared_depth=carried)  # before session 13
    assert old.meta["reason"] == "low_parallax_shared_depth"
    assert old.meta["pnp_failed"] == [4, 5, 6]  # the view has left the strip: poses copied
    assert _rotation_errors(old, frames).max() > 8.0  # measured 9.2 deg: the turn is lost

    enc = _encoder().encode(frames, shared_depth=carried)  # the default
    assert enc.meta["pnp_failed"] == [] and enc.meta["pnp_rotation_only"] == [4, 5, 6]
    err = _rotation_errors(enc, frames)
    assert err.max() < 0.3, err  # measured 0.08 deg
    assert np.linalg.norm(enc.T_local_cam[:, :3, 3], axis=1).max() < 0.02  # no baseline invented
    # the carried depth ran out: the last frames hand on a placeholder plane, not measured depth
    assert enc.meta.get("placeholder_depth")


def test_a_window_after_a_placeholder_says_its_scale_is_a_guess(turn):
    frames, _ = turn
    plane = np.full((240, 320), 2.0, np.float32)  # what a window that ran out of carried depth hands on
    enc = _encoder(mono_turn_rotation=True).encode(frames, shared_depth=plane)
    assert enc.meta["shared_placeholder"] and enc.meta["reason"] == "low_parallax_unit_depth"
    measured = _encoder().encode(frames, shared_depth=turn[1])
    assert not measured.meta.get("shared_placeholder")
