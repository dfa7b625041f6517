"""The tracking suite's long synthetic room rows parse, plan and open (docs/evaluation.md, "A long synthetic room")."""

from __future__ import annotations

import numpy as np

from gsslam.datasets.base import open_dataset
from gsslam.run.manifest import load_manifest


def test_synth_room_rows_load_and_open(tmp_path):
    import yaml

    m = load_manifest("tracking")
    rows = {s.name: s for s in m.sequences if s.name.startswith("synth_room1000")}
    assert set(rows) == {f"synth_room1000{k}_{mode}" for k in ("", "_kinect") for mode in ("rgbd", "mono")}
    runs = [r for r in m.runs([]) if r.sequence.name in rows]
    assert len(runs) == 8 and not any(r.missing for r in runs)  # generated: no data needed; loops on / off
    kinect = rows["synth_room1000_kinect_rgbd"].kwargs
    exact = rows["synth_room1000_rgbd"].kwargs
    assert {k: v for k, v in kinect.items() if k not in ("sensor", "misregister", "degrade")} == exact
    # as the batch opens a generated scene: its kwargs as a YAML the loader reads
    p = tmp_path / "synthetic.yaml"
    p.write_text(yaml.safe_dump(kinect))
    ds = open_dataset("synthetic", p)
    assert len(ds) == 1000 and ds.sensor is not None and ds.misregistration.report == "depth"
    assert ds.ground_truth_camera == "depth"  # as 7-Scenes gives it: the depth camera's poses
    f = ds[500]
    assert f.image.shape == (240, 320, 3) and f.depth.shape == (240, 320)
    assert 0.8 < np.isfinite(f.depth).mean() < 1.0  # holes where the sensor gives none
    assert ds.intrinsics.fx > ds.true_intrinsics.fx * 1.1  # the depth camera's focal handed out
