"""Manifests: parsing, modes and grids, data-root resolution, suites, errors a user can act on."""

from __future__ import annotations

import pytest

from gsslam.run.manifest import (
    ManifestError,
    available_suites,
    data_roots,
    load_manifest,
    parse_manifest,
    resolve_data_path,
)


def _m(**kw):
    data = {
        "sequences": [{"name": "teddy", "path": "rgbd_dataset_freiburg3_teddy_60", "mode": ["rgbd", "mono"]}]
    }
    data.update(kw)
    return parse_manifest(data)


def test_modes_expand_and_defaults_apply():
    m = _m(defaults={"frames": [0, 12], "set": ["loop.enabled=false"]},
           configs=[{"name": "a"}, {"name": "b", "set": ["keyframes.max_gap=5"]}])  # fmt: skip
    assert [s.name for s in m.sequences] == ["teddy_rgbd", "teddy_mono"]
    assert all(s.frames == 12 and s.dataset == "tum" for s in m.sequences)
    assert [v.overrides for v in m.variants] == [
        ("loop.enabled=false",),
        ("loop.enabled=false", "keyframes.max_gap=5"),
    ]


def test_grid_crosses_configs():
    m = _m(grid={"mapper.iterations": [10, 20], "loop.enabled": [True, False]})
    assert [v.name for v in m.variants] == [
        "mapper.iterations=10_loop.enabled=on", "mapper.iterations=10_loop.enabled=off",
        "mapper.iterations=20_loop.enabled=on", "mapper.iterations=20_loop.enabled=off",
    ]  # fmt: skip
    assert m.variants[1].overrides == ("mapper.iterations=10", "loop.enabled=false")
    m2 = _m(configs=[{"name": "x"}, {"name": "y"}], grid={"mapper.iterations": [10, 20]})
    assert [v.name for v in m2.variants] == ["x_mapper.iterations=10", "x_mapper.iterations=20",
                                              "y_mapper.iterations=10", "y_mapper.iterations=20"]  # fmt: skip


def test_runs_resolve_data_and_mark_missing(tmp_path, bundled_tum):
    m = parse_manifest({"sequences": [
        {"name": "here", "path": bundled_tum.name},
        {"name": "absent", "path": "no_such_sequence"},
        {"name": "gen", "dataset": "synthetic", "kwargs": {"n_frames": 10}},
        {"name": "gt_absent", "path": bundled_tum.name, "ground_truth": "nope/groundtruth.txt"},
    ], "configs": [{"name": "c1"}, {"name": "c2"}]})  # fmt: skip
    runs = m.runs([tmp_path, bundled_tum.parent])
    assert [r.run_id for r in runs][:3] == ["here__c1", "here__c2", "absent__c1"]
    by = {r.run_id: r for r in runs}
    assert by["here__c1"].data_path == bundled_tum.resolve() and not by["here__c1"].missing
    assert by["absent__c1"].missing and by["gt_absent__c2"].missing
    assert not by["gen__c1"].missing and by["gen__c1"].data_path is None
    assert by["here__c1"].fingerprint() != by["here__c2"].fingerprint()  # the config name is part of it


def test_fingerprint_changes_with_what_decides_the_result(bundled_tum):
    def fp(**seq):
        s = {"name": "t", "path": str(bundled_tum), **seq}
        return parse_manifest({"sequences": [s]}).runs([])[0].fingerprint()

    assert fp() == fp()
    assert fp(frames=10) == fp(frames=[0, 10])  # a start at 0 is the old spelling: same fingerprint
    assert len({fp(), fp(frames=10), fp(frames=[5, 15]), fp(mode="rgbd"), fp(kwargs={"max_dt": 0.01})}) == 5


def test_frames_range_sets_start_and_count():
    m = _m(defaults={"frames": [30, 50]})
    assert all((s.start, s.frames) == (30, 20) for s in m.sequences)


def test_data_roots_env_and_resolution(tmp_path, monkeypatch):
    (tmp_path / "seq").mkdir()
    monkeypatch.setenv("GSSLAM_DATA", str(tmp_path))
    roots = data_roots()
    assert roots[0] == tmp_path
    assert resolve_data_path("seq", roots) == (tmp_path / "seq").resolve()
    assert resolve_data_path("rgbd_dataset_freiburg3_teddy_60", roots) is not None  # repo data/
    assert resolve_data_path(str(tmp_path / "missing"), roots) is None


@pytest.mark.parametrize(
    "data, match",
    [
        ({"sequences": []}, "non-empty"),
        ({"sequences": [{"name": "a"}]}, "'path' is required"),
        ({"sequences": [{"name": "a b", "path": "x"}]}, "letters, digits"),
        ({"sequences": [{"name": "a", "path": "x", "frames": [10, 5]}]}, "START < STOP"),
        ({"sequences": [{"name": "a", "path": "x", "frames": [-1, 5]}]}, "START < STOP"),
        ({"sequences": [{"name": "a", "path": "x", "mode": "stereo"}]}, "mono or rgbd"),
        ({"sequences": [{"name": "a", "path": "x", "typo": 1}]}, "unknown keys"),
        ({"sequences": [{"name": "a", "path": "x"}, {"name": "a", "path": "y"}]}, "unique"),
        (
            {"sequences": [{"name": "a", "path": "x"}], "configs": [{"name": "c", "set": ["noequals"]}]},
            "section.key",
        ),
    ],
)
def test_bad_manifests(data, match):
    with pytest.raises(ManifestError, match=match):
        parse_manifest(data)


def test_builtin_suites_parse():
    assert {"quick", "standard", "long"} <= set(available_suites())
    quick = load_manifest("quick")
    assert quick.name == "quick" and len(quick.sequences) >= 2
    long = load_manifest("long")
    assert {s.dataset for s in long.sequences} == {"playback", "synthetic"}
    assert any("misregister" in s.kwargs for s in long.sequences)
    with pytest.raises(ManifestError, match="unknown suite"):
        load_manifest("no-such-suite")
