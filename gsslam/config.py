"""Typed, frozen configuration tree, loaded from YAML with dotted ``key=value`` overrides.

Each stage owns one section dataclass. ``load_config(path, overrides)`` starts from the
defaults below, applies a YAML file (only keys that exist are accepted) and then the overrides,
e.g. ``["mapper.iterations=50", "loop.enabled=false"]``. The resolved config is written next to
every result with :func:`save_config`.

Every loaded value is range-checked (:func:`validate_config`, table ``RANGES``): a value out of its
range raises :class:`ConfigError` naming the key, the value, where it was set and the valid range.
"""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path
from typing import Any

import yaml

from gsslam.config_ranges import RANGES, Range, validate_config
from gsslam.config_schema import (
    Config,
    ConfigError,
    EncoderConfig,
    FlowConfig,
    GraphConfig,
    ImuConfig,
    KeyframeConfig,
    LoopConfig,
    MapperConfig,
    PipelineConfig,
    RunConfig,
)

__all__ = [
    "RANGES",
    "Config",
    "ConfigError",
    "EncoderConfig",
    "FlowConfig",
    "GraphConfig",
    "ImuConfig",
    "KeyframeConfig",
    "LoopConfig",
    "MapperConfig",
    "PipelineConfig",
    "Range",
    "RunConfig",
    "config_to_dict",
    "load_config",
    "parse_override",
    "read_config_file",
    "save_config",
    "validate_config",
]


def _coerce(value: Any, typ: Any, key: str) -> Any:
    """Convert ``value`` (from YAML or a string override) to the annotated type ``typ``."""
    if typ is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "1", "yes", "on", "false", "0", "no", "off"):
            return value.lower() in ("true", "1", "yes", "on")
        raise ConfigError(f"{key}: expected true/false, got {value!r}")
    if typ is int:
        try:
            if isinstance(value, float) and not value.is_integer():
                raise ValueError
            return int(value)
        except (TypeError, ValueError):
            raise ConfigError(f"{key}: expected an integer, got {value!r}") from None
    if typ is float:
        try:
            return float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"{key}: expected a number, got {value!r}") from None
    if typ is str:
        return str(value)
    return value


def _apply(obj: Any, updates: dict, prefix: str = "") -> Any:
    hints = typing.get_type_hints(type(obj))
    names = {f.name for f in dataclasses.fields(obj)}
    changes = {}
    for key, value in updates.items():
        full = f"{prefix}{key}"
        if key not in names:
            raise ConfigError(f"unknown config key '{full}' (known: {', '.join(sorted(names))})")
        current = getattr(obj, key)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, dict):
                raise ConfigError(f"'{full}' is a section; give its keys, e.g. {full}.<key>=...")
            changes[key] = _apply(current, value, f"{full}.")
        else:
            changes[key] = _coerce(value, hints[key], full)
    return dataclasses.replace(obj, **changes)


def parse_override(text: str) -> dict:
    """``"a.b=3"`` -> ``{"a": {"b": "3"}}`` (the value is coerced later, by the field's type)."""
    if "=" not in text:
        raise ConfigError(f"override '{text}' must look like section.key=value")
    key, value = text.split("=", 1)
    parts = key.strip().split(".")
    out: dict = {}
    node = out
    for p in parts[:-1]:
        node = node.setdefault(p, {})
    node[parts[-1]] = yaml.safe_load(value) if value.strip() else ""
    return out


def _dotted_keys(updates: dict, prefix: str = "") -> list[str]:
    out = []
    for k, v in updates.items():
        out += _dotted_keys(v, f"{prefix}{k}.") if isinstance(v, dict) else [f"{prefix}{k}"]
    return out


def read_config_file(path: str | Path) -> dict:
    """The mapping of sections in a YAML config file; unreadable, binary or malformed files raise."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"config file not found: {p}")
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ConfigError(f"config file {p} is not a text file (binary data?); write YAML sections") from None
    except OSError as e:
        raise ConfigError(f"cannot read config file {p}: {e.strerror}") from None
    try:
        data = yaml.safe_load(text) or {}
    except yaml.YAMLError as e:
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ConfigError(f"config file {p} is not valid YAML ({first}); fix or remove it") from None
    if not isinstance(data, dict):
        raise ConfigError(f"config file {p} must hold a mapping of sections")
    return data


def load_config(path: str | Path | None = None, overrides: list[str] | None = None, **top: Any) -> Config:
    """Defaults, then the YAML file at ``path``, then dotted ``overrides``, then keyword top-level keys.

    The result is range-checked (:func:`validate_config`); the error names where a bad value was set.
    """
    cfg = Config()
    sources: dict[str, str] = {}
    if path is not None:
        data = read_config_file(path)
        try:
            cfg = _apply(cfg, data)
        except ConfigError as e:
            raise ConfigError(f"config file {path}: {e}") from None
        sources.update(dict.fromkeys(_dotted_keys(data), f"in config file {path}"))
    for text in overrides or []:
        update = parse_override(text)
        cfg = _apply(cfg, update)
        sources.update(dict.fromkeys(_dotted_keys(update), f"by override '{text}'"))
    if top:
        given = {k: v for k, v in top.items() if v is not None}
        cfg = _apply(cfg, given)
        sources.update(dict.fromkeys(given, "by argument"))
    validate_config(cfg, sources)
    return cfg


# ------------------------------------------------------------------------------------------- ranges


def config_to_dict(cfg: Any) -> dict:
    return dataclasses.asdict(cfg)


def save_config(cfg: Config, path: str | Path) -> None:
    from gsslam.io.atomic import atomic_write_text

    atomic_write_text(path, yaml.safe_dump(config_to_dict(cfg), sort_keys=False))
