"""Batch manifests: which sequences to run with which configuration variants (frozen, from YAML).

A manifest is a YAML mapping::

    name: my-table                  # default: the file name
    defaults:                       # applied to every sequence / variant below
      frames: 120                   # run frames [0, 120); [300, 420] runs frames 300..419
      set: [loop.enabled=true]      # overrides put before every variant's own
    sequences:
      - name: teddy                 # unique; names the run folders
        path: rgbd_dataset_freiburg3_teddy   # relative to a data root (or absolute)
        dataset: tum                # a registered loader (gsslam.datasets)
        mode: [mono, rgbd]          # one mode or a list (expands to teddy_mono, teddy_rgbd)
        ground_truth: null          # optional file, passed to the loader as gt_path
        kwargs: {}                  # any further loader keyword arguments
      - name: room_loop             # no path: a generated scene (synthetic); kwargs are its parameters
        dataset: synthetic
        kwargs: {n_frames: 600, trajectory: loop}
    configs:                        # named variants (default: one, "default", no overrides)
      - {name: default, set: []}
      - {name: few-iters, set: [mapper.iterations=20]}
    grid:                           # optional: every combination, crossed with each config
      mapper.max_side: [120, 160]

Paths are resolved by :func:`resolve_data_path` against the data roots (:func:`data_roots`); a sequence
whose data is absent is kept in the plan with ``path=None`` and reported as skipped.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from gsslam.errors import GsslamError

SUITES_DIR = Path(__file__).resolve().parent / "suites"
DATA_ENV = "GSSLAM_DATA"
_NAME_OK = re.compile(r"^[A-Za-z0-9._+=-]+$")


class ManifestError(GsslamError):
    """A batch manifest is missing, not valid YAML, or holds an unknown key or a bad value."""


@dataclass(frozen=True)
class SequenceSpec:
    """One sequence to run: ``path`` as written (``None`` for a generated scene).

    ``frames`` = how many frames to run (``None``: all), from frame ``start``.
    """

    name: str
    dataset: str
    path: str | None = None
    mode: str | None = None
    ground_truth: str | None = None
    frames: int | None = None
    kwargs: dict[str, Any] = field(default_factory=dict)
    start: int = 0


@dataclass(frozen=True)
class Variant:
    """A named configuration: dotted ``--set`` overrides, applied in order."""

    name: str
    overrides: tuple[str, ...] = ()


@dataclass(frozen=True)
class RunSpec:
    """One run of the batch: a sequence (its data resolved, or ``None`` when absent) with a variant."""

    sequence: SequenceSpec
    variant: Variant
    data_path: Path | None
    gt_path: Path | None

    @property
    def run_id(self) -> str:
        return f"{self.sequence.name}__{self.variant.name}"

    @property
    def missing(self) -> bool:
        return self.data_path is None and self.sequence.path is not None

    def to_dict(self) -> dict:
        s = self.sequence
        return {
            "run_id": self.run_id,
            "sequence": s.name,
            "config": self.variant.name,
            "dataset": s.dataset,
            "path": None if self.data_path is None else str(self.data_path),
            "mode": s.mode,
            "ground_truth": None if self.gt_path is None else str(self.gt_path),
            "frames": s.frames,
            **({"start": s.start} if s.start else {}),  # absent at 0: older batches keep their fingerprints
            "kwargs": s.kwargs,
            "overrides": list(self.variant.overrides),
        }

    def fingerprint(self) -> str:
        """Hash of everything that decides the run's result; a finished run with another one re-runs."""
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Manifest:
    name: str
    sequences: tuple[SequenceSpec, ...]
    variants: tuple[Variant, ...]
    source: Path | None = None

    def runs(self, roots: list[Path]) -> list[RunSpec]:
        """Every (sequence, variant) pair, sequence-major, with data paths resolved against ``roots``."""
        out = []
        for s in self.sequences:
            data = None if s.path is None else resolve_data_path(s.path, roots)
            gt = None if s.ground_truth is None else resolve_data_path(s.ground_truth, roots)
            if s.ground_truth is not None and gt is None:
                data = None  # without its ground truth the run cannot be evaluated: report it as skipped
            out.extend(RunSpec(s, v, data, gt) for v in self.variants)
        return out


def data_roots(extra: list[Path] | None = None, manifest: Manifest | None = None) -> list[Path]:
    """Where relative data paths are looked up, in order: ``extra`` (``--data-root``), ``$GSSLAM_DATA``
    (``os.pathsep``-separated), the manifest's folder, ``data/`` and ``../shared/data`` beside the
    checkout, and ``./data``."""
    roots = [Path(p) for p in extra or []]
    roots += [Path(p) for p in os.environ.get(DATA_ENV, "").split(os.pathsep) if p]
    if manifest is not None and manifest.source is not None and manifest.source.parent != SUITES_DIR:
        roots.append(manifest.source.parent)
    repo = Path(__file__).resolve().parents[2]
    roots += [repo / "data", repo.parent / "shared" / "data", Path.cwd() / "data"]
    seen, out = set(), []
    for r in roots:
        key = str(r.resolve()) if r.exists() else str(r)
        if key not in seen:
            seen.add(key)
            out.append(r)
    return out


def resolve_data_path(path: str, roots: list[Path]) -> Path | None:
    p = Path(os.path.expanduser(path))
    if p.is_absolute():
        return p if p.exists() else None
    for root in roots:
        if (root / p).exists():
            return (root / p).resolve()
    return None


def available_suites() -> list[str]:
    return sorted(p.stem for p in SUITES_DIR.glob("*.yaml"))


def suite_path(name: str) -> Path:
    p = SUITES_DIR / f"{name}.yaml"
    if not p.is_file():
        raise ManifestError(f"unknown suite {name!r}; choose one of: {', '.join(available_suites())}")
    return p


def load_manifest(path: str | Path) -> Manifest:
    """Read a manifest file, or a built-in suite when ``path`` is a suite name (``quick``, ...)."""
    p = Path(path)
    if not p.exists() and p.suffix == "" and len(p.parts) == 1:
        p = suite_path(str(path))
    if not p.is_file():
        raise ManifestError(f"manifest not found: {p} (built-in suites: {', '.join(available_suites())})")
    try:
        data = yaml.safe_load(p.read_text())
    except yaml.YAMLError as e:
        raise ManifestError(f"manifest {p} is not valid YAML: {e}") from None
    return parse_manifest(data, default_name=p.stem, source=p.resolve(), where=str(p))


def _check_keys(d: Any, known: set[str], where: str) -> dict:
    if not isinstance(d, dict):
        raise ManifestError(f"{where}: expected a mapping, got {type(d).__name__}")
    unknown = set(d) - known
    if unknown:
        raise ManifestError(f"{where}: unknown keys {sorted(unknown)}; known: {', '.join(sorted(known))}")
    return d


def _check_name(name: Any, where: str) -> str:
    if not isinstance(name, str) or not _NAME_OK.match(name):
        raise ManifestError(f"{where}: name {name!r} must be letters, digits and . _ + = - only")
    return name


def _frames(value: Any, where: str) -> tuple[int, int | None]:
    """``frames: N`` (the first N) or ``[START, STOP]`` (frames START..STOP-1) -> (start, count)."""
    if value is None:
        return 0, None
    start = 0
    if isinstance(value, list | tuple):
        ok = len(value) == 2 and all(isinstance(v, int) and not isinstance(v, bool) for v in value)
        if not ok or not 0 <= value[0] < value[1]:
            raise ManifestError(
                f"{where}: frames must be N or [START, STOP] with 0 <= START < STOP, got {value!r}"
            )
        start, value = value[0], value[1] - value[0]
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise ManifestError(f"{where}: frames must be a positive integer, got {value!r}")
    return start, value


def _overrides(value: Any, where: str) -> tuple[str, ...]:
    if value is None:
        return ()
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not all(isinstance(v, str) and "=" in v for v in value):
        raise ManifestError(f"{where}: 'set' must be a list of section.key=value strings, got {value!r}")
    return tuple(value)


def _sequences(items: Any, defaults: dict) -> list[SequenceSpec]:
    if not isinstance(items, list) or not items:
        raise ManifestError("manifest: 'sequences' must be a non-empty list")
    known = {"name", "path", "dataset", "mode", "ground_truth", "frames", "kwargs"}
    out = []
    for k, item in enumerate(items):
        where = f"sequences[{k}]"
        d = _check_keys(item, known, where)
        name = _check_name(d.get("name"), where)
        dataset = d.get("dataset", "tum")
        path = d.get("path")
        if path is None and dataset != "synthetic":
            raise ManifestError(f"{where} ({name}): 'path' is required (only a synthetic scene has none)")
        kwargs = {**defaults.get("kwargs", {}), **(d.get("kwargs") or {})}
        if not isinstance(kwargs, dict):
            raise ManifestError(f"{where} ({name}): 'kwargs' must be a mapping")
        modes = d.get("mode")
        modes = modes if isinstance(modes, list) else [modes]
        for mode in modes:
            if mode not in (None, "mono", "rgbd"):
                raise ManifestError(f"{where} ({name}): mode must be mono or rgbd, got {mode!r}")
            full = f"{name}_{mode}" if len(modes) > 1 else name
            start, frames = _frames(d.get("frames", defaults.get("frames")), where)
            gt = d.get("ground_truth")
            out.append(SequenceSpec(full, str(dataset), path, mode, gt, frames, dict(kwargs), start))
    return out


def _variants(configs: Any, grid: Any, base: tuple[str, ...]) -> list[Variant]:
    if configs is None:
        configs = [{"name": "default"}]
    if not isinstance(configs, list) or not configs:
        raise ManifestError("manifest: 'configs' must be a non-empty list of {name, set}")
    variants = []
    for k, c in enumerate(configs):
        d = _check_keys(c, {"name", "set"}, f"configs[{k}]")
        name = _check_name(d.get("name"), f"configs[{k}]")
        variants.append(Variant(name, base + _overrides(d.get("set"), f"configs[{k}]")))
    if grid:
        g = _check_keys(grid, set(grid), "grid")
        keys = list(g)
        for key in keys:
            if not isinstance(g[key], list) or not g[key]:
                raise ManifestError(f"grid: {key} must be a non-empty list of values")
        crossed = []
        for v in variants:
            for combo in itertools.product(*(g[key] for key in keys)):
                sets = tuple(f"{key}={json.dumps(val) if isinstance(val, bool) else val}" for key, val in
                             zip(keys, combo))  # fmt: skip
                tag = "_".join(s.replace("true", "on").replace("false", "off") for s in sets)
                name = tag if len(variants) == 1 and v.name == "default" else f"{v.name}_{tag}"
                crossed.append(Variant(_check_name(name, "grid"), v.overrides + sets))
        variants = crossed
    names = [v.name for v in variants]
    if len(set(names)) != len(names):
        raise ManifestError(f"manifest: configuration names must be unique, got {names}")
    return variants


def parse_manifest(
    data: Any, default_name: str = "batch", source: Path | None = None, where: str = ""
) -> Manifest:
    d = _check_keys(
        data, {"name", "defaults", "sequences", "configs", "grid", "description"}, where or "manifest"
    )
    defaults = _check_keys(d.get("defaults") or {}, {"frames", "set", "kwargs"}, "defaults")
    seqs = _sequences(d.get("sequences"), defaults)
    names = [s.name for s in seqs]
    if len(set(names)) != len(names):
        raise ManifestError(f"manifest: sequence names must be unique, got {names}")
    variants = _variants(d.get("configs"), d.get("grid"), _overrides(defaults.get("set"), "defaults"))
    name = _check_name(d.get("name", default_name), "manifest")
    return Manifest(name, tuple(seqs), tuple(variants), source)
