"""MapStage feedback paths with a stub map: what the next submap and the graph receive."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from gsslam.config import MapperConfig
from gsslam.slam.map_stage import MapStage


def _stage(depth: torch.Tensor, alpha: torch.Tensor, scale: float) -> tuple[MapStage, list]:
    stage = MapStage.__new__(MapStage)  # no real mapper: render_keyframe is all shared_depth reads
    stage.cfg = MapperConfig()
    stage.mapper = SimpleNamespace(render_keyframe=lambda index: SimpleNamespace(depth=depth, alpha=alpha))
    stage._anchor = {7: (0, 0, 0)}
    stage.pending_owner, stage.n_registrations_relative, stage.owner_shares = {}, 0, []
    S = np.diag([scale, scale, scale, 1.0])
    chains = [SimpleNamespace(T_world_chain=np.eye(4), graph=SimpleNamespace(submap_pose=lambda s: S))]
    return stage, chains


def test_shared_depth_replaces_only_measured_opaque_pixels():
    """Inpainted pixels (no point-map depth) and half-transparent ones keep the encoder's depth."""
    h, w = 6, 8
    depth = torch.full((h, w), 4.0)  # world units
    alpha = torch.ones(h, w)
    alpha[:, w // 2 :] = 0.5
    stage, chains = _stage(depth, alpha, scale=2.0)
    pointmap = np.full((h, w), 1.5, np.float32)
    pointmap[:2] = np.nan  # the texture mask left these without depth
    out = stage.shared_depth(chains, 7, pointmap)
    assert np.all(np.isnan(out[:2]))  # never filled from the map's inpainted Gaussians
    np.testing.assert_allclose(out[2:, : w // 2], 2.0)  # rendered, in submap units (4 m / scale 2)
    np.testing.assert_allclose(out[2:, w // 2 :], 1.5)  # alpha 0.5: the encoder's own depth
    assert stage.shared_depth(chains, 99, pointmap) is pointmap  # not a mapper keyframe


def test_registrations_go_to_the_chain_frame_with_their_information():
    """A chain drawn at half size in the world: poses in chain units, translation information / 4."""
    from gsslam.mapping.registration import Registration

    sent = {}
    graph = SimpleNamespace(
        add_registration=lambda sid, pos, T, info: sent.update(sid=sid, pos=pos, T=T, info=info)
    )
    T_world_chain = np.diag([0.5, 0.5, 0.5, 1.0])  # x_world = 0.5 x_chain: chain units are twice as small
    T_world_chain[:3, 3] = [1.0, 0.0, 0.0]
    chain = SimpleNamespace(T_world_chain=T_world_chain, graph=graph)
    T_world_cam = np.eye(4)
    T_world_cam[:3, 3] = [2.0, 1.0, 0.0]
    info = np.diag([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    stage, _ = _stage(torch.zeros(1, 1), torch.zeros(1, 1), 1.0)
    stage.n_registrations = 0
    stage.pending = [(3, Registration(11, T_world_cam, info, 0.9, 0.03, 1e4, 10.0))]
    assert stage.send_registrations(chain, 5) == 1
    assert sent["sid"] == 5 and sent["pos"] == [3] and stage.pending == []
    np.testing.assert_allclose(sent["T"][0][:3, 3], [2.0, 2.0, 0.0])  # (t_world - (1, 0, 0)) / 0.5
    np.testing.assert_allclose(sent["T"][0][:3, :3], np.eye(3))
    # a residual of 1 chain unit is 0.5 world units: information / 4 on translation
    np.testing.assert_allclose(np.diag(sent["info"][0]), [1.0, 2.0, 3.0, 1.0, 1.25, 1.5])


def test_unconverged_registrations_are_withheld_not_sent():
    """A registration the mapper returns with weight 0 (its Gauss-Newton did not reach the map's minimum,
    mapper.registration_unconverged_weight=0) is counted and kept aside, never sent to the graph; gated
    ones (None) are counted as before; a converged one is sent."""
    from gsslam.mapping.registration import Registration

    T = np.eye(4)
    regs = {
        4: Registration(4, T, np.eye(6), 0.9, 0.03, 1e4, 10.0),  # converged: sent
        5: Registration(5, T, np.zeros((6, 6)), 0.9, 0.03, 1e4, 10.0, 1.0, False, False, 0.0),  # refused
        6: None,  # gated
    }
    stage, chains = _stage(torch.zeros(1, 1), torch.zeros(1, 1), 1.0)
    stage.mapper = SimpleNamespace(register=lambda frame, T_wc, pts, conf: regs[frame])
    stage.n_registrations = stage.n_registrations_gated = stage.n_registrations_withheld = 0
    stage.withheld = []
    chains[0].encodings = []
    enc = SimpleNamespace(
        frame_indices=[3, 4, 5, 6], T_local_cam=[np.eye(4)] * 4, points_cam=[None] * 4, confidence=[None] * 4
    )
    stage.pending = stage._register(chains, 0, 0, enc, {i: i for i in range(3, 7)}, [4, 5, 6])
    assert [p for p, _ in stage.pending] == [1]  # keyframe 4 only, at its position in the submap
    assert stage.n_registrations_withheld == 1 and [r.index for r in stage.withheld] == [5]
    assert stage.n_registrations_gated == 1
    sent = {}
    chain = SimpleNamespace(
        T_world_chain=np.eye(4), graph=SimpleNamespace(add_registration=lambda *a: sent.update(a=a))
    )
    assert stage.send_registrations(chain, 0) == 1 and len(sent["a"][1]) == 1


@pytest.mark.parametrize("split", [0.0, 0.1])
def test_relative_registrations_go_to_their_owner_submap_in_its_units(split):
    """mapper.registration_relative: a registration whose view is owned by submap 1 of the same chain
    (drawn at scale 2, shifted by (1, 0, 0) in the world) is sent as a relative factor (1 -> 4), the camera
    in submap 1's frame and units, translation information x 4; one whose owners are all in another chain
    falls back to the absolute prior on submap 4. With mapper.registration_owner_split=0.1 submap 2 (share
    0.2) gets a factor too, the information split 0.8 / 0.2."""
    from gsslam.mapping.registration import Registration

    S1 = np.diag([2.0, 2.0, 2.0, 1.0])
    S1[:3, 3] = [1.0, 0.0, 0.0]
    sent = {}
    graph = SimpleNamespace(
        submap_pose=lambda s: S1 if s == 1 else np.eye(4),
        add_relative_registration=lambda o, sid, pos, T, I: sent.update({("rel", o): (o, sid, pos, T, I)}),
        add_registration=lambda sid, pos, T, info: sent.update(abs=(sid, pos)),
    )
    chain = SimpleNamespace(T_world_chain=np.eye(4), graph=graph, encodings=[None] * 5)
    T_world_cam = np.eye(4)
    T_world_cam[:3, 3] = [3.0, 1.0, 0.0]
    info = np.diag([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    regs = {7: Registration(7, T_world_cam, info, 0.9, 0.03, 1e4, 10.0),
            8: Registration(8, T_world_cam, info, 0.9, 0.03, 1e4, 10.0)}  # fmt: skip
    owners = {7: {10: 0.8, 11: 0.2}, 8: {12: 1.0}}  # mapper submap ids: 10 = (0, 1), 11 = (0, 2), 12 = (1, 0)
    stage, _ = _stage(torch.zeros(1, 1), torch.zeros(1, 1), 1.0)
    stage.cfg = MapperConfig(
        registration_feedback=True, registration_relative=True, registration_owner_split=split
    )
    stage._gid = {(0, 1): 10, (0, 2): 11, (1, 0): 12}
    stage.mapper = SimpleNamespace(
        register=lambda frame, T_wc, pts, conf: regs[frame],
        registration_owners=lambda T: owners[7] if T is regs[7].T_world_cam else owners[8],
    )
    regs[8] = dataclasses.replace(regs[8], T_world_cam=T_world_cam.copy())
    stage.n_registrations = stage.n_registrations_gated = stage.n_registrations_withheld = 0
    enc = SimpleNamespace(frame_indices=[6, 7, 8], T_local_cam=[np.eye(4)] * 3, points_cam=[None] * 3,
                          confidence=[None] * 3)  # fmt: skip
    stage.pending = stage._register([chain], 0, 4, enc, {i: i for i in range(6, 9)}, [7, 8])
    assert stage.send_registrations(chain, 4) == 2
    o, sid, pos, T, I = sent[("rel", 1)]
    assert (o, sid, pos) == (1, 4, [1]) and sent["abs"] == (4, [2])
    np.testing.assert_allclose(T[0][:3, 3], [1.0, 0.5, 0.0])  # ((3, 1, 0) - (1, 0, 0)) / 2
    np.testing.assert_allclose(T[0][:3, :3], np.eye(3))
    w = 0.8 if split else 1.0
    np.testing.assert_allclose(np.diag(I[0]), w * np.array([1.0, 2.0, 3.0, 16.0, 20.0, 24.0]))
    assert (("rel", 2) in sent) == bool(split)
    if split:
        o, sid, pos, T, I = sent[("rel", 2)]  # submap 2 at the world origin, scale 1
        assert (o, sid, pos) == (2, 4, [1])
        np.testing.assert_allclose(T[0][:3, 3], [3.0, 1.0, 0.0])
        np.testing.assert_allclose(np.diag(I[0]), 0.2 * np.diag(info))
    assert stage.n_registrations == 2 and stage.n_registrations_relative == 1
    assert stage.owner_shares == pytest.approx([1.0 if split else 0.8])
