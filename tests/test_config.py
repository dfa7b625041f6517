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
    with pytest.raises(ConfigError, match="mode must be"):
        load_config(mode="stereo")


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
