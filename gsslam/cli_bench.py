"""``gsslam bench ...``: benchmarks that print timing numbers (added to the app by gsslam.cli)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Optional

import typer

from gsslam.cli_batch import run_manifest

bench_app = typer.Typer(help="Benchmarks that print timing numbers (not tests).", no_args_is_help=True)


def _int_list(text: str, option: str) -> list[int]:
    """``"50,200"`` -> ``[50, 200]``; anything else is a usage error naming the option."""
    try:
        values = [int(s) for s in text.split(",")]
    except ValueError:
        raise typer.BadParameter(f"expected comma-separated integers like 50,200, got {text!r}",
                                 param_hint=option) from None  # fmt: skip
    if any(v <= 0 for v in values):
        raise typer.BadParameter(f"every value must be positive, got {text!r}", param_hint=option)
    return values


@bench_app.command("accuracy")
def bench_accuracy(
    suite: Annotated[
        str, typer.Option(help="Built-in suite: quick | standard | long | tracking | feedback.")
    ] = "quick",
    jobs: Annotated[int, typer.Option(help="Runs at once (> 1 needs gsslam\\[batch]).")] = 1,
    address: Annotated[Optional[str], typer.Option(help="Ray cluster address.")] = None,
    out: Annotated[Optional[Path], typer.Option(help="Batch folder (default runs/batch/<suite>).")] = None,
    max_frames: Annotated[Optional[int], typer.Option(help="Cap every sequence at N frames.")] = None,
    data_root: Annotated[
        Optional[list[Path]], typer.Option(help="Extra folder to find the suite's data in (repeatable).")
    ] = None,
) -> None:
    """Accuracy table of a built-in suite: `gsslam batch SUITE` (see docs/evaluation.md)."""
    from gsslam.run.manifest import suite_path

    run_manifest(str(suite_path(suite)), out, jobs, address, max_frames, data_root)


def _bench(name: str, fn: str = "run", **kwargs) -> None:
    import importlib

    mod = importlib.import_module(f"gsslam.bench.{name}")
    result = getattr(mod, fn)(**kwargs)
    typer.echo(json.dumps(result, indent=2))


@bench_app.command("graph")
def bench_graph(
    sizes: Annotated[str, typer.Option(help="Comma-separated keyframe counts.")] = "50,200,800",
    points: Annotated[int, typer.Option(help="Flow correspondences per keyframe pair.")] = 1000,
    imu: Annotated[bool, typer.Option(help="Add CombinedImuFactors (synthesized 200 Hz IMU).")] = False,
) -> None:
    """iSAM2 update time per keyframe and batch LM time on a synthetic chain."""
    _bench("graph", sizes=_int_list(sizes, "--sizes"), points=points, imu=imu)


@bench_app.command("raster")
def bench_raster(
    gaussians: Annotated[int, typer.Option(help="Number of Gaussians.")] = 20000,
    width: Annotated[int, typer.Option()] = 160,
    height: Annotated[int, typer.Option()] = 120,
    repeats: Annotated[int, typer.Option()] = 10,
) -> None:
    """Forward+backward time of the rasterizer (CPU, and CUDA when present)."""
    _bench("raster", gaussians=gaussians, width=width, height=height, repeats=repeats)


@bench_app.command("pipeline")
def bench_pipeline(
    path: Annotated[Optional[Path], typer.Argument(help="TUM-layout sequence (default: bundled).")] = None,
    max_frames: Annotated[int, typer.Option()] = 60,
    mode: Annotated[str, typer.Option()] = "rgbd",
    lengths: Annotated[
        Optional[str],
        typer.Option(
            help="Comma-separated lengths, e.g. 200,500,1000: whole runs (map and loops on) of the "
            "sequence played by --pattern; per-stage ms per frame and memory."
        ),
    ] = None,
    pattern: Annotated[str, typer.Option(help="Playback pattern for --lengths (f forward, b back).")] = (
        "fbfbfb"
    ),
    map_on: Annotated[
        bool, typer.Option("--map/--no-map", help="With --lengths: mapper and loops on.")
    ] = True,
    plot: Annotated[Optional[Path], typer.Option(help="With --lengths: PNG of memory against frame.")] = None,
    set_: Annotated[
        Optional[list[str]], typer.Option("--set", help="With --lengths: config override for every run.")
    ] = None,
) -> None:
    """Tracking + graph FPS without the mapper; with --lengths, the whole run's cost by stage and length."""
    if lengths:
        _bench("pipeline", fn="run_lengths", path=path, mode=mode, pattern=pattern, map_on=map_on, plot=plot,
               lengths=tuple(int(x) for x in lengths.split(",")), overrides=list(set_ or []))  # fmt: skip
        return
    _bench("pipeline", path=path, max_frames=max_frames, mode=mode)


@bench_app.command("map-cost")
def bench_map_cost(
    path: Annotated[Optional[Path], typer.Argument(help="Sequence folder (default: bundled 60).")] = None,
    dataset: Annotated[str, typer.Option()] = "tum",
    mode: Annotated[str, typer.Option()] = "rgbd",
    sides: Annotated[str, typer.Option(help="Comma-separated mapper.max_side values; full = input size.")] = (
        "160,240,320"
    ),
    max_frames: Annotated[Optional[int], typer.Option(min=1)] = None,
    set_: Annotated[Optional[list[str]], typer.Option("--set", help="Config override for every run.")] = None,
) -> None:
    """Whole runs: map off, then one per mapper resolution; CPU ratio to map off and native PSNR."""
    full = [t.strip() == "full" for t in sides.split(",")]
    values = _int_list(",".join("1" if f else t for f, t in zip(full, sides.split(","))), "--sides")
    sides_ = tuple("full" if f else v for f, v in zip(full, values))
    _bench("map_cost", path=path, dataset=dataset, mode=mode, sides=sides_,
           max_frames=max_frames, overrides=list(set_ or []))  # fmt: skip


@bench_app.command("mapper")
def bench_mapper(
    path: Annotated[Optional[Path], typer.Argument(help="TUM-layout sequence (default: bundled).")] = None,
    max_frames: Annotated[int, typer.Option()] = 60,
    kf_every: Annotated[int, typer.Option(help="Keyframe every N frames (ground-truth poses).")] = 10,
    iterations: Annotated[int, typer.Option(help="Optimisation steps per keyframe.")] = 30,
    sides: Annotated[
        str, typer.Option(help="Comma-separated mapper resolutions (max side, px).")
    ] = "120,160",
) -> None:
    """Mapper alone on ground-truth poses: PSNR, map size, time per keyframe for each resolution."""
    _bench(
        "mapper", path=path, max_frames=max_frames, kf_every=kf_every, iterations=iterations,
        sides=tuple(_int_list(sides, "--sides")),
    )  # fmt: skip


@bench_app.command("loop")
def bench_loop(
    sizes: Annotated[str, typer.Option(help="Comma-separated submap counts.")] = "10,100,500",
) -> None:
    """Loop-detection time per submap as the map grows."""
    _bench("loop", sizes=_int_list(sizes, "--sizes"))
