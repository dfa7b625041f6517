"""The mono chain's earlier depths rendered into a keyframe whose carried depth a turn exhausted."""

from __future__ import annotations

import numpy as np

from gsslam.slam.chains import Chain, ChainKeyframe
from gsslam.slam.world_depth import encode_with_world_depth, exhausted_depth, rendered_depth
from gsslam.types import CameraIntrinsics, SubmapEncoding

W, H, F = 64, 48, 50.0
INTR = CameraIntrinsics(F, F, (W - 1) / 2, (H - 1) / 2, W, H)
WALL_Z = 3.0  # the wall z = 3 in the chain frame (chain units)


class _Graph:
    """The two things rendered_depth asks of a chain's graph: keyframe poses and submap scales."""

    def __init__(self, poses, owners, scales):
        self.poses, self.owners, self.scales = poses, owners, scales

    def owner(self, index):
        return self.owners[index]

    def keyframe_pose(self, index):
        return self.poses[index]

    def submap_pose(self, sid):
        S = np.eye(4)
        S[:3, :3] *= self.scales[sid]
        return S


def _rot_y(a: float) -> np.ndarray:  # [3, 3]
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _wall_depth(T: np.ndarray) -> np.ndarray:  # [H, W] z of the wall in the camera T (chain units)
    v, u = np.mgrid[0:H, 0:W]
    rays = np.stack([(u - INTR.cx) / F, (v - INTR.cy) / F, np.ones((H, W))], -1) @ T[:3, :3].T
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (WALL_Z - T[2, 3]) / rays[..., 2]  # ray parameter = camera z (unit z in the camera)
    return np.where(t > 0, t, np.nan)


def _scene(turn_deg: float):
    """Keyframe 0 (submap 0, scale 0.5) faces the wall; keyframe 9 (submap 1, scale 2) has turned."""
    T0 = np.eye(4)
    T9 = np.eye(4)
    T9[:3, :3] = _rot_y(np.radians(turn_deg))
    T9[:3, 3] = [0.2, 0.0, 0.1]
    scales = {0: 0.5, 1: 2.0}
    d0 = (_wall_depth(T0) / scales[0]).astype(np.float32)  # submap-0 units
    enc0 = SubmapEncoding(
        [0], np.eye(4)[None], np.zeros((1, H, W, 3), np.float32), np.ones((1, H, W), np.float32), INTR
    )
    enc0.points_cam[0, ..., 2] = d0  # only the depths are read (through the keyframe)
    enc1 = SubmapEncoding(
        [9], np.eye(4)[None], np.zeros((1, H, W, 3), np.float32), np.zeros((1, H, W), np.float32), INTR
    )
    graph = _Graph({0: T0, 9: T9}, {0: (0, 0), 9: (1, 0)}, scales)
    chain = Chain(graph=graph, T_world_chain=np.eye(4), encodings=[enc0, enc1])
    plane = np.full((H, W), 1.234, np.float32)  # the placeholder keyframe 9 was left with
    keyframes = {0: ChainKeyframe(0, 0, 0, d0), 9: ChainKeyframe(0, 1, 0, plane)}
    truth = _wall_depth(T9) / scales[1]  # submap-1 units
    return chain, keyframes, truth, plane


def test_rendered_depth_is_the_earlier_geometry_in_the_owner_submaps_units():
    chain, kfs, truth, _ = _scene(turn_deg=25.0)
    got, n = rendered_depth(chain, [chain], kfs, 9, INTR.K, (H, W))
    assert n == 1  # keyframe 9's own placeholder (confidence 0) is no source
    has = np.isfinite(got)
    # the overlap of two 65 deg views 25 deg apart, 0.2 to the side (measured 0.46 of the view)
    assert 0.40 < has.mean() < 0.55
    rel = np.abs(got[has] / truth[has] - 1.0)
    # cells of 2 px on a slanted wall: measured median 0.44 %, 95th percentile 0.91 %
    assert np.median(rel) < 0.008 and np.percentile(rel, 95) < 0.015


def test_exhausted_depth_replaces_only_a_placeholder():
    chain, kfs, truth, plane = _scene(turn_deg=25.0)
    out, conf = exhausted_depth(chain, [chain], kfs, 9, 30, plane, None)
    has = np.isfinite(out)
    assert has.sum() > 30 and np.allclose(conf[has], 0.5) and np.all(conf[~has] == 0)
    measured = truth.astype(np.float32)  # a carried depth that still measures the view stays as it is
    same, c = exhausted_depth(chain, [chain], kfs, 9, 30, measured, None)
    assert same is measured and c is None


def test_exhausted_depth_keeps_the_placeholder_when_nothing_earlier_is_in_view():
    chain, kfs, _, plane = _scene(turn_deg=120.0)  # turned away from everything the chain measured
    out, conf = exhausted_depth(chain, [chain], kfs, 9, 30, plane, None)
    assert out is plane and conf is None


def test_a_carried_sliver_is_kept_and_the_rendered_depth_fills_the_rest():
    """``encoder.mono_world_depth_unlinked``: a carried depth left on a strip at the edge the turn leaves
    (8 of 64 columns) still measures something, but the next window's own depth cannot link to it."""
    chain, kfs, truth, _ = _scene(turn_deg=25.0)
    sliver = np.full((H, W), np.nan, np.float32)
    sliver[:, :8] = 1.05 * truth[:, :8]  # the carried depth: its own values, 5 % off the rendered ones
    sconf = np.where(np.isfinite(sliver), 0.8, 0.0).astype(np.float32)
    same, c = exhausted_depth(chain, [chain], kfs, 9, 30, sliver, sconf)  # linked: kept
    assert same is sliver and c is sconf
    out, conf = exhausted_depth(chain, [chain], kfs, 9, 30, sliver, sconf, unlinked=True)
    own = np.isfinite(sliver)
    assert np.array_equal(out[own], sliver[own]) and np.all(conf[own] == 0.8)
    fill = ~own & np.isfinite(out)
    assert 0.3 < fill.mean() < 0.45  # measured 0.38 (the rendered overlap, less the sliver)
    assert np.all(conf[fill] == 0.5)
    assert np.median(np.abs(out[fill] / truth[fill] - 1.0)) < 0.008


class _Encoder:
    """Records the shared depth of each call; its window's meta says "unlinked" while ``unlinked``."""

    def __init__(self, unlinked: bool):
        self.unlinked, self.calls = unlinked, []

    def encode(self, frames, shared_depth=None, shared_confidence=None):
        self.calls.append(shared_depth)
        enc = SubmapEncoding(
            [9], np.eye(4)[None], np.zeros((1, H, W, 3), np.float32), np.ones((1, H, W), np.float32), INTR
        )
        enc.meta = {"unlinked": True} if self.unlinked and len(self.calls) == 1 else {}
        return enc


class _Frame:
    index = 9


def test_a_window_is_encoded_against_the_rendered_depth_and_says_so():
    chain, kfs, truth, plane = _scene(turn_deg=25.0)
    args = (chain, [chain], kfs)
    enc_plane = _Encoder(unlinked=False)  # the placeholder is replaced before the (single) encoding
    out = encode_with_world_depth(enc_plane, [_Frame()], *args, plane, None, 30, unlinked=True)
    assert len(enc_plane.calls) == 1 and enc_plane.calls[0] is not plane and out.meta["world_depth"]
    measured = truth.astype(np.float32)  # a carried depth that measures the view and links: as it is
    enc_kept = _Encoder(unlinked=False)
    out = encode_with_world_depth(enc_kept, [_Frame()], *args, measured, None, 30, unlinked=True)
    assert enc_kept.calls == [measured] and "world_depth" not in out.meta
    sliver = np.full((H, W), np.nan, np.float32)
    sliver[:, :8] = truth[:, :8]
    enc_sliver = _Encoder(unlinked=True)  # the window could not link to the sliver: encoded again, filled
    out = encode_with_world_depth(enc_sliver, [_Frame()], *args, sliver, None, 30, unlinked=True)
    assert len(enc_sliver.calls) == 2 and enc_sliver.calls[0] is sliver and out.meta["world_depth"]
    assert np.isfinite(enc_sliver.calls[1]).sum() > 2 * np.isfinite(sliver).sum()
    enc_off = _Encoder(unlinked=True)  # encoder.mono_world_depth_unlinked off: one encoding, the sliver
    out = encode_with_world_depth(enc_off, [_Frame()], *args, sliver, None, 30, unlinked=False)
    assert enc_off.calls == [sliver] and "world_depth" not in out.meta
