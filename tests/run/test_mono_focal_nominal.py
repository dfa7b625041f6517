"""A mono run calibrates its focal when the dataset says its intrinsics are nominal (the 7-Scenes hand-out:
the depth camera's intrinsics for colour), and only then unless ``encoder.mono_focal_auto`` asks always."""

from __future__ import annotations

from pathlib import Path

import pytest

import gsslam.run.registration as seq
from gsslam.config import load_config
from gsslam.datasets import open_dataset
from gsslam.datasets.synthetic import SyntheticDataset
from gsslam.types import CameraIntrinsics
from helpers.sevenscenes import write_sequence


@pytest.fixture
def calls(monkeypatch):  # frames per self-calibration (the estimate itself: test_mono_focal.py)
    seen = []

    def fake(frames, flow, enc):
        seen.append(len(frames))
        return 1.0, None

    monkeypatch.setattr(seq, "mono_focal_correction", fake)
    return seen


def test_seven_scenes_intrinsics_are_nominal_unless_given(tmp_path):
    write_sequence(tmp_path / "seq-01", n=2)
    assert open_dataset("7scenes", tmp_path / "seq-01").intrinsics_nominal
    own = CameraIntrinsics(525.0, 525.0, 320.0, 240.0, 640, 480)
    assert not open_dataset("7scenes", tmp_path / "seq-01", intrinsics=own).intrinsics_nominal


def test_synthetic_hand_outs_say_whether_their_focal_is_the_camera_s():
    kw = dict(n_frames=3, width=64, height=48)
    assert not SyntheticDataset(**kw).intrinsics_nominal
    assert SyntheticDataset(focal_scale=1.114, **kw).intrinsics_nominal
    mis = dict(baseline_m=0.025, focal_scale=1.114)
    assert SyntheticDataset(misregister={**mis, "report": "depth"}, **kw).intrinsics_nominal
    assert not SyntheticDataset(misregister={**mis, "report": "colour"}, **kw).intrinsics_nominal


def test_mono_run_calibrates_nominal_intrinsics_only(tmp_path, calls):
    write_sequence(tmp_path / "seq-01", n=3)
    nominal = open_dataset("7scenes", tmp_path / "seq-01", with_depth=False)
    own = CameraIntrinsics(525.0, 525.0, 320.0, 240.0, 640, 480)
    calibrated = open_dataset("7scenes", tmp_path / "seq-01", with_depth=False, intrinsics=own)
    mono = load_config(None, [], mode="mono")
    assert seq.mono_focal_calibration(nominal, mono, None) == (1.0, None) and calls == [3]
    seq.mono_focal_calibration(calibrated, mono, None)
    assert calls == [3]  # its own intrinsics: trusted
    seq.mono_focal_calibration(calibrated, load_config(None, ["encoder.mono_focal_auto=true"], mode="mono"), None)
    assert calls == [3, 3]  # asked for always
    seq.mono_focal_calibration(nominal, load_config(None, ["encoder.mono_focal_auto_nominal=false"], mode="mono"), None)
    seq.mono_focal_calibration(nominal, load_config(None, [], mode="rgbd"), None)  # RGB-D registers depth instead
    assert calls == [3, 3]


def test_playback_handed_out_as_seven_scenes_is_nominal():
    teddy = str(Path(__file__).resolve().parents[2] / "data" / "rgbd_dataset_freiburg3_teddy_60")
    mis = dict(baseline_m=0.025, focal_scale=1.114)
    as_7scenes = open_dataset(
        "playback", teddy, base="tum", pattern="f", misregister={**mis, "report": "depth"}
    )
    as_tum = open_dataset("playback", teddy, base="tum", pattern="f", misregister={**mis, "report": "colour"})
    assert as_7scenes.intrinsics_nominal and not as_tum.intrinsics_nominal
