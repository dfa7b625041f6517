"""Loop closure inside the pipeline on a real revisit: bundled TUM teddy played forward then backward."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.datasets.revisit import RevisitDataset
from gsslam.run.sequence import run_dataset

pytestmark = pytest.mark.slow  # end-to-end runs


def test_revisit_dataset_mirrors_frames_and_ground_truth(bundled_tum):
    base = open_dataset("tum", bundled_tum)
    ds = RevisitDataset(base, 10)
    assert len(ds) == 19
    assert [ds.source_index(i) for i in (0, 9, 10, 18)] == [0, 9, 8, 0]
    ts = np.array(ds.timestamps())
    assert np.all(np.diff(ts) > 0)
    f, g = ds[12], base[6]
    assert f.index == 12 and np.array_equal(f.image, g.image)
    gt = ds.ground_truth()
    assert np.all(np.diff(gt.timestamps) > 0)
    # the pose at a mirrored time is the pose at the original time
    j = int(np.argmin(np.abs(gt.timestamps - ts[12])))
    k = int(np.argmin(np.abs(gt.timestamps - ts[6])))
    assert np.allclose(gt.poses[j], gt.poses[k], atol=1e-3)


@pytest.fixture(scope="module")
def revisit_runs(bundled_tum, tmp_path_factory):
    ds = RevisitDataset(open_dataset("tum", bundled_tum))  # 60 frames forward + 59 back
    out = {}
    for loops in ("true", "false"):
        cfg = load_config(None, ["mapper.enabled=false", f"loop.enabled={loops}"], mode="mono")
        out[loops] = run_dataset(ds, cfg, tmp_path_factory.mktemp(f"loops_{loops}")).metrics
    return out


def test_loops_found_on_the_revisit_and_do_not_hurt(revisit_runs):
    on, off = revisit_runs["true"], revisit_runs["false"]
    lp = on["loop_closure"]
    assert lp["enabled"] and lp["accepted"] >= 1 and lp["in_graph"] >= 1
    assert all(e["m"] < e["i"] for e in lp["loops"])
    # measured 2.18 cm with loops vs 2.34 cm without (Sim(3)-aligned, 119 frames)
    assert on["ate"]["rmse_m"] <= off["ate"]["rmse_m"] + 1e-4
    assert on["frames_posed"] >= 110


def test_loops_off_finds_nothing(revisit_runs):
    lp = revisit_runs["false"]["loop_closure"]
    assert not lp["enabled"] and lp["detected"] == 0 and lp["in_graph"] == 0
