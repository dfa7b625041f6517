"""The ``gsslam`` command line: a thin layer over the library.

Heavy modules are imported inside each command. Every error is printed as one line on stderr
(``error: ...``), never a traceback (``-v`` logs it), and the exit status says what happened
(docs/run_folders.md):

==========  ===============================================================================
status      meaning
==========  ===============================================================================
0           success
1           runtime failure: an unexpected error inside gsslam or the machine (a bug, out of
            memory, disk full); rerun with ``-v`` for the traceback
2           usage or input error: bad arguments, options or config values, a malformed or
            missing input file, an unusable output folder; the message names what to fix
130 / 143   interrupted by SIGINT (Ctrl-C) / SIGTERM; a run writes the outputs it has first
==========  ===============================================================================
"""

from __future__ import annotations

import errno
import json
import logging
import signal
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from gsslam.cli_batch import batch_cmd
from gsslam.cli_bench import bench_app
from gsslam.cli_progress import StageBar
from gsslam.errors import GsslamError

app = typer.Typer(
    name="gsslam",
    help="Dense monocular / RGB-D SLAM: GTSAM iSAM2 graph + 3D Gaussian map.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
app.add_typer(bench_app, name="bench")

_log = logging.getLogger("gsslam")


def _setup_logging(verbose: bool) -> None:
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )


def _echo_table(rows: list[tuple[str, str]], title: str | None = None) -> None:
    if title:
        typer.echo(title)
    width = max((len(k) for k, _ in rows), default=0)
    for k, v in rows:
        typer.echo(f"  {k:<{width}}  {v}")


@app.callback()
def _main(verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Debug logging.")] = False) -> None:
    _setup_logging(verbose)


@app.command("eval")
def eval_cmd(
    gt: Annotated[Path, typer.Argument(help="Ground-truth trajectory file.")],
    est: Annotated[Path, typer.Argument(help="Estimated trajectory file.")],
    align: Annotated[str, typer.Option(help="Alignment before ATE: sim3 | se3 | none.")] = "sim3",
    fmt: Annotated[str, typer.Option("--format", help="File format of both files: tum | kitti.")] = "tum",
    max_dt: Annotated[
        float,
        typer.Option(
            help="Max timestamp difference for association (s). evo's --t_max_diff defaults to 0.01; "
            "pass --t_max_diff 0.02 to evo for the same pairs."
        ),
    ] = 0.02,
    rpe_delta: Annotated[int, typer.Option(help="RPE frame delta.")] = 1,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
    plot: Annotated[
        Optional[Path], typer.Option(help="Write a PNG: aligned estimate over ground truth.")
    ] = None,
) -> None:
    """ATE (after Umeyama alignment) and RPE of EST against GT.

    Poses are paired by timestamp: nearest within --max-dt, one-to-one (KITTI: line index = time).
    The estimate is aligned to GT: sim3 (monocular), se3 (RGB-D, stereo) or none.
    Prints ATE (position error, m) and RPE over --rpe-delta frames (translation m, rotation deg).
    Definitions match evo's ape/rpe; see docs/evaluation.md.
    """
    from gsslam.run.evaluate import evaluate_files

    report = evaluate_files(gt, est, align=align, fmt=fmt, max_dt=max_dt, rpe_delta=rpe_delta, plot=plot)
    if as_json:
        typer.echo(json.dumps(report.to_dict(), indent=2))
    else:
        _echo_table(report.table_rows(), title=f"{est} vs {gt} (align={align})")


@app.command("run")
def run_cmd(
    path: Annotated[Path, typer.Argument(help="Sequence folder (or video file for --dataset images).")],
    dataset: Annotated[
        str, typer.Option(help="tum | euroc | kitti | 7scenes | images | rosbag | synthetic")
    ] = "tum",
    mode: Annotated[Optional[str], typer.Option(help="mono | rgbd (default: the config's, mono)")] = None,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("runs/latest"),
    config: Annotated[Optional[Path], typer.Option(help="YAML config file.")] = None,
    set_: Annotated[
        Optional[list[str]], typer.Option("--set", help="Override, e.g. mapper.iterations=20")
    ] = None,
    max_frames: Annotated[Optional[int], typer.Option(min=1, help="Use only the first N frames.")] = None,
    start_frame: Annotated[
        int, typer.Option(min=0, help="Skip the first N frames (--max-frames counts from there).")
    ] = 0,
    intrinsics: Annotated[Optional[Path], typer.Option(help="Intrinsics YAML (images dataset).")] = None,
    progress: Annotated[bool, typer.Option(help="Show a progress bar.")] = True,
    overwrite: Annotated[
        bool, typer.Option(help="Replace an older run in OUT (removes only gsslam's own files).")
    ] = False,
    dataset_arg: Annotated[
        Optional[list[str]],
        typer.Option("--dataset-arg", help="Loader option KEY=VALUE (YAML value), e.g. image_topic=/cam/rgb"),
    ] = None,
    viz: Annotated[
        Optional[str], typer.Option(help="Also record a viewer file: rerun (OUT/run.rrd).")
    ] = None,
    resume: Annotated[
        bool,
        typer.Option(help="Continue the interrupted run in OUT from its last checkpoint (same arguments)."),
    ] = False,
    imu: Annotated[
        bool, typer.Option("--imu", help="Preintegrated IMU factors between keyframes (imu.enabled=true).")
    ] = False,
) -> None:
    """Run SLAM on a sequence; writes trajectory, config, metrics, plots and the map to OUT.

    OUT must not hold another run (see --overwrite, --resume) and takes one run at a time (a lock file).
    Every run.checkpoint_every submaps and on SIGINT/SIGTERM the run state is saved in OUT/checkpoint.
    """
    from gsslam.config import load_config
    from gsslam.run.sequence import run_sequence

    if viz not in (None, "rerun"):
        raise typer.BadParameter(f"unknown viewer {viz!r}; the only one is 'rerun'", param_hint="--viz")
    cfg = load_config(config, (set_ or []) + (["imu.enabled=true"] if imu else []), mode=mode)
    ds_kwargs = _dataset_args(dataset_arg or [])
    if intrinsics is not None:
        if dataset not in ("images", "tum", "rosbag"):
            raise typer.BadParameter(
                f"--intrinsics is for --dataset images, tum or rosbag; {dataset} reads its own calibration",
                param_hint="--intrinsics",
            )
        ds_kwargs["intrinsics_file"] = intrinsics
    bar = StageBar() if progress else None
    try:
        result = run_sequence(
            path, dataset, cfg, out, max_frames=max_frames, progress=bar.frames if bar else False,
            stages=bar.stage if bar else None, overwrite=overwrite, start_frame=start_frame, resume=resume,
            **ds_kwargs,
        )  # fmt: skip
    finally:
        if bar is not None:
            bar.close()
    _echo_table(result.summary_rows(), title=f"gsslam run -> {out}")
    if viz == "rerun":
        from gsslam.viz.rerun_log import record_run

        typer.echo(f"rerun recording: {record_run(out, out / 'run.rrd')}")


def _dataset_args(items: list[str]) -> dict:
    import yaml

    kwargs = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise typer.BadParameter(f"expected KEY=VALUE, got {item!r}", param_hint="--dataset-arg")
        kwargs[key.strip()] = yaml.safe_load(value) if value.strip() else None
    return kwargs


@app.command("export")
def export_cmd(
    run_dir: Annotated[Path, typer.Argument(help="Output folder of a `gsslam run`.")],
    fmt: Annotated[str, typer.Option("--format", help="colmap | nerfstudio | inria")] = "colmap",
    out: Annotated[Optional[Path], typer.Option(help="Export folder (default RUN/export_FORMAT).")] = None,
    images: Annotated[bool, typer.Option(help="Copy the keyframe images into OUT/images.")] = False,
    sh_degree: Annotated[int, typer.Option(help="SH degree of the INRIA PLY (f_rest_* zero-padded).")] = 3,
    iteration: Annotated[int, typer.Option(help="N of point_cloud/iteration_N (INRIA).")] = 30000,
) -> None:
    """Export a run's keyframe cameras and map for COLMAP, nerfstudio/gsplat or the INRIA 3DGS tools."""
    from gsslam.run.export import export_run

    path = export_run(run_dir, fmt, out, images=images, sh_degree=sh_degree, iteration=iteration)
    typer.echo(f"wrote {fmt} export to {path} (docs/exports.md)")


@app.command("view")
def view_cmd(
    run_dir: Annotated[Path, typer.Argument(help="Output folder of a `gsslam run`.")],
    rrd: Annotated[
        Optional[Path], typer.Option(help="Recording to write/open (default RUN/run.rrd).")
    ] = None,
    spawn: Annotated[bool, typer.Option(help="Open the rerun viewer on the recording.")] = True,
) -> None:
    """Record a run folder for the rerun viewer (needs the `viz` extra) and open it."""
    from gsslam.viz.rerun_log import open_viewer, record_run

    rrd = rrd or run_dir / "run.rrd"
    if not rrd.is_file():
        record_run(run_dir, rrd)
    typer.echo(f"rerun recording: {rrd}")
    if spawn:
        open_viewer(rrd)


DEMO_SEQUENCE = "data/rgbd_dataset_freiburg3_teddy_60"  # in a clone of gsslam


@app.command("demo")
def demo_cmd(
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("runs/demo"),
    data: Annotated[
        Optional[Path], typer.Option(help=f"TUM sequence (default: {DEMO_SEQUENCE} of the clone).")
    ] = None,
    set_: Annotated[
        Optional[list[str]], typer.Option("--set", help="Override, e.g. mapper.iterations=20")
    ] = None,
    max_frames: Annotated[Optional[int], typer.Option(help="Use only the first N frames.")] = None,
    progress: Annotated[bool, typer.Option(help="Show a progress bar.")] = True,
) -> None:
    """RGB-D SLAM on the bundled TUM fr3/teddy frames, then ATE/RPE against its ground truth."""
    from gsslam.run.evaluate import evaluate_files

    if data is None:
        here, checkout = Path.cwd(), Path(__file__).resolve().parents[1]
        data = next((p / DEMO_SEQUENCE for p in (here, checkout) if (p / DEMO_SEQUENCE).is_dir()), None)
        if data is None:
            raise typer.BadParameter(
                f"{DEMO_SEQUENCE} not found; run from a clone of gsslam or pass --data", param_hint="--data"
            )
    # the demo's own folder: a previous demo in it is replaced (only gsslam's files)
    run_cmd(
        data, "tum", "rgbd", out, config=None, set_=set_, max_frames=max_frames, intrinsics=None,
        progress=progress, overwrite=True,
    )  # fmt: skip
    report = evaluate_files(
        data / "groundtruth.txt", out / "trajectory.tum", align="se3", plot=out / "ate.png"
    )
    _echo_table(report.table_rows(), title="trajectory vs ground truth (align=se3)")
    typer.echo(f"outputs in {out}/: trajectory.tum, metrics.json, map.ply, renders/, ate.png")


@app.command("render")
def render_cmd(
    run_dir: Annotated[Path, typer.Argument(help="Output folder of a `gsslam run` (holds map.ply).")],
    out: Annotated[Path, typer.Option(help="Folder for the rendered PNGs.")] = Path("renders"),
    every: Annotated[int, typer.Option(min=1, help="Render every N-th pose of trajectory.tum.")] = 10,
    size: Annotated[
        Optional[str],
        typer.Option(help="Render size WxH, e.g. 640x480 (default: the mapper's resolution)."),
    ] = None,
) -> None:
    """Render frames from a saved Gaussian map along the saved trajectory."""
    from gsslam.run.render import parse_size, render_run

    n = render_run(run_dir, out, every=every, size=parse_size(size) if size else None)
    typer.echo(f"wrote {n} renders to {out}")


app.command("batch")(batch_cmd)


EXIT_OK = 0
EXIT_FAILURE = 1  # runtime failure (unexpected error)
EXIT_USAGE = 2  # usage or input error the user can fix
EXIT_SIGINT = 128 + signal.SIGINT  # 130
EXIT_SIGTERM = 128 + signal.SIGTERM  # 143
# OSError numbers that mean "this path cannot be used as given": the user fixes the path
_PATH_ERRNOS = (
    errno.ENOENT,
    errno.ENOTDIR,
    errno.EISDIR,
    errno.EACCES,
    errno.EPERM,
    errno.EEXIST,
    errno.EROFS,
)


def _one_line(text: str) -> str:
    return " ".join(part.strip() for part in str(text).splitlines() if part.strip())


def _fail(message: str, code: int) -> int:
    typer.echo(f"error: {_one_line(message)}", err=True)
    return code


def run_cli(argv: list[str] | None = None) -> int:
    """Run the command line on ``argv`` (default ``sys.argv[1:]``) and return the exit status.

    SIGTERM is turned into the same interruption as Ctrl-C, so a killed run writes its outputs.
    """
    try:  # typer >= 0.16 carries its own copy of click; older versions use click itself
        from typer._click import exceptions as click
    except ImportError:
        from click import exceptions as click

    received: list[int] = []

    def on_term(signum: int, _frame) -> None:
        received.append(signum)
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, on_term)
    try:
        rv = app(args=argv, prog_name="gsslam", standalone_mode=False)
        if isinstance(rv, int) and rv == 130:  # typer turns KeyboardInterrupt into exit 130
            typer.echo("interrupted", err=True)
            return EXIT_SIGTERM if received else EXIT_SIGINT
        return rv if isinstance(rv, int) else EXIT_OK
    except GsslamError as e:
        _log.debug("gsslam error", exc_info=True)
        if received:  # the interruption surfaced as another error (e.g. inside an import)
            typer.echo("interrupted", err=True)
            return EXIT_SIGTERM
        return _fail(str(e), EXIT_USAGE)
    except click.UsageError as e:
        if not e.format_message():  # no arguments at all: the help was shown
            return EXIT_USAGE
        where = f" (see '{e.ctx.command_path} --help')" if e.ctx is not None else ""
        return _fail(e.format_message() + where, EXIT_USAGE)
    except click.ClickException as e:
        return _fail(e.format_message(), e.exit_code)
    except (KeyboardInterrupt, typer.Abort):
        typer.echo("interrupted", err=True)
        return EXIT_SIGTERM if received else EXIT_SIGINT
    except OSError as e:
        _log.debug("OS error", exc_info=True)
        if e.errno in _PATH_ERRNOS and e.filename is not None:
            return _fail(f"cannot use {e.filename}: {e.strerror}; check the path", EXIT_USAGE)
        return _fail(f"{e} (rerun with -v for the traceback)", EXIT_FAILURE)
    except Exception as e:  # a bug or the machine: one line, the traceback with -v
        _log.debug("unexpected error", exc_info=True)
        if received:  # SIGTERM raised inside an extension's import shows up as ImportError
            typer.echo("interrupted", err=True)
            return EXIT_SIGTERM
        return _fail(
            f"unexpected {type(e).__name__}: {e} (a bug? rerun with -v for the traceback)", EXIT_FAILURE
        )
    finally:
        signal.signal(signal.SIGTERM, previous)


def main() -> None:
    raise SystemExit(run_cli())


if __name__ == "__main__":
    main()
