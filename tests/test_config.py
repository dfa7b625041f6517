import dataclasses
from pathlib import Path

import pytest
import yaml

from gsslam.config import Config, ConfigError, load_config, parse_override, save_config


def test_defaults_match_the_papers():
    cfg = load_config()
    assert cfg.encoder.submap_size == 6  # SING3R K
    assert cfg.mapper.lambda_depth == 5.0  # lambda_D
    assert cfg.mapper.lambda_depth_normal == 0.05  # lambda_DN
    assert cfg.mapper.lambda_scale == 10.0  # lambda_S
    assert cfg.mapper.lambda_pose_depth == 10.0


def test_overrides_are_typed():
    cfg = load_config(overrides=["mapper.iterations=7", "loop.enabled=false", "graph.scale_sigma=0.5"])
    assert cfg.mapper.iterations == 7 and isinstance(cfg.mapper.iterations, int)
    assert cfg.loop.enabled is False
    assert cfg.graph.scale_sigma == 0.5


def test_yaml_then_overrides(tmp_path: Path):
    p = tmp_path / "c.yaml"
    p.write_text("mode: rgbd\nmapper:\n  iterations: 3\n  window: 4\n")
    cfg = load_config(p, ["mapper.window=5"])
    assert (cfg.mode, cfg.mapper.iterations, cfg.mapper.window) == ("rgbd", 3, 5)


def test_save_then_load_round_trip(tmp_path: Path):
    cfg = load_config(overrides=["flow.dis_preset=fast", "seed=3"], mode="rgbd")
    save_config(cfg, tmp_path / "config.yaml")
    assert load_config(tmp_path / "config.yaml") == cfg
    assert yaml.safe_load((tmp_path / "config.yaml").read_text())["flow"]["dis_preset"] == "fast"


@pytest.mark.parametrize(
    "override, message",
    [
        ("mapper.nope=1", "unknown config key 'mapper.nope'"),
        ("mapper.iterations=abc", "expected an integer"),
        ("loop.enabled=maybe", "expected true/false"),
        ("mapper=3", "is a section"),
        ("novalue", "must look like"),
    ],
)
def test_bad_overrides_say_what_is_wrong(override, message):
    with pytest.raises(ConfigError, match=message):
        load_config(overrides=[override])


def test_bad_files(tmp_path: Path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("mapper: [1, 2\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(bad)
    with pytest.raises(
        ConfigError, match="mode=.stereo. set by argument is out of range: must be one of .mono., .rgbd."
    ):
        load_config(mode="stereo")


def test_every_key_has_a_range():
    """A new config key needs an entry in gsslam.config.RANGES (numeric range or string choices)."""
    from gsslam.config_ranges import RANGES, _leaves

    missing = [k for k, v in _leaves(Config()) if not isinstance(v, bool) and k not in RANGES]
    # free-form strings: the flow method is extensible (frontend.flow.register_flow_method)
    missing = [k for k in missing if k != "flow.method"]
    assert not missing, f"add ranges for {missing} to gsslam.config.RANGES"
    stale = [k for k in RANGES if k not in dict(_leaves(Config()))]
    assert not stale, f"RANGES names keys that no longer exist: {stale}"


@pytest.mark.parametrize(
    "override, message",
    [
        ("encoder.submap_size=-3", r"encoder\.submap_size=-3 set by override .* must be an integer >= 1"),
        ("graph.flow_sigma_px=nan", r"graph\.flow_sigma_px=nan .* must be a finite number > 0"),
        ("graph.flow_sigma_px=.inf", r"graph\.flow_sigma_px=inf .* must be a finite number > 0"),
        ("pipeline.track_points=0", r"pipeline\.track_points=0 .* must be an integer >= 8"),
        ("mapper.lambda_ssim=1.5", r"mapper\.lambda_ssim=1\.5 .* <= 1"),
        ("mapper.device=gpu", r"mapper\.device='gpu' .* one of 'auto', 'cpu', 'cuda'"),
        ("encoder.min_depth=20", r"encoder\.max_depth=10\.0 \(the default\) .* > encoder\.min_depth"),
    ],
)
def test_values_are_range_checked(override, message):
    with pytest.raises(ConfigError, match=message):
        load_config(overrides=[override])


def test_range_errors_name_the_file_and_cross_checks_see_the_final_values(tmp_path: Path):
    p = tmp_path / "c.yaml"
    p.write_text("loop:\n  min_score: 2.0\n")
    with pytest.raises(ConfigError, match=rf"loop\.min_score=2\.0 set in config file {p}"):
        load_config(p)
    # order of overrides does not matter: only the final values are checked
    cfg = load_config(overrides=["encoder.min_depth=20", "encoder.max_depth=50"])
    assert (cfg.encoder.min_depth, cfg.encoder.max_depth) == (20.0, 50.0)
    garbage = tmp_path / "garbage.yaml"
    garbage.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(ConfigError, match="not a text file"):
        load_config(garbage)


def test_config_is_frozen():
    cfg = Config()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.mapper.iterations = 3  # type: ignore[misc]


def test_parse_override_nesting():
    assert parse_override("a.b.c=1") == {"a": {"b": {"c": 1}}}


def test_unset_cli_mode_keeps_the_files_mode(tmp_path: Path):
    p = tmp_path / "c.yaml"
    p.write_text("mode: rgbd\n")
    assert load_config(p, [], mode=None).mode == "rgbd"  # `gsslam run` without --mode
    assert load_config(p, [], mode="mono").mode == "mono"  # an explicit --mode wins
