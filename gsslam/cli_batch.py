"""``gsslam batch``: run a manifest's sequences x configurations (registered on the app by gsslam.cli)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer


def run_manifest(
    manifest: str, out: Optional[Path], jobs: int, address: Optional[str], max_frames: Optional[int],
    data_root: Optional[list[Path]],
) -> None:  # fmt: skip
    from gsslam.run.batch import BatchOptions, run_batch
    from gsslam.run.manifest import load_manifest

    m = load_manifest(manifest)
    opts = BatchOptions(
        out=out or Path("runs") / "batch" / m.name, jobs=jobs, address=address, max_frames=max_frames,
        data_roots=tuple(data_root or ()),
    )  # fmt: skip

    def done(rec: dict) -> None:
        err = f": {rec.get('error')}" if rec.get("error") else ""
        typer.echo(f"  {rec.get('run_id')}: {rec.get('status')}{err}", err=True)

    result = run_batch(m, opts, on_done=done)
    typer.echo((opts.out / "results.md").read_text())
    typer.echo(
        f"{len(result.executed)} run(s) executed, {len(result.reused)} reused; "
        f"tables in {opts.out}/results.{{md,csv,json}}, plot {opts.out}/ate.png"
    )


def batch_cmd(
    manifest: Annotated[
        Optional[str],
        typer.Argument(help="Manifest YAML, or a built-in suite: quick, standard, long, feedback."),
    ] = None,
    jobs: Annotated[
        int, typer.Option(help="Runs at once (> 1 runs on a local Ray; needs gsslam\\[batch]).")
    ] = 1,
    address: Annotated[
        Optional[str],
        typer.Option(help="Ray cluster, e.g. ray://HOST:10001 (out and data on shared storage)."),
    ] = None,
    out: Annotated[
        Optional[Path], typer.Option(help="Batch folder (default runs/batch/<manifest name>).")
    ] = None,
    max_frames: Annotated[Optional[int], typer.Option(help="Cap every sequence at N frames.")] = None,
    data_root: Annotated[
        Optional[list[Path]], typer.Option(help="Extra folder to find relative data paths in (repeatable).")
    ] = None,
    compare: Annotated[
        Optional[tuple[Path, Path]], typer.Option(help="Print B - A per sequence for two batch folders A B.")
    ] = None,
) -> None:
    """Run every sequence x configuration of a manifest; resume; write one table (md, csv, json) + plot.

    Each run gets its own folder OUT/runs/<sequence>__<config>; runs already complete are skipped, so
    re-running a batch finishes what is missing. A failed run is a row with its error. Data paths are
    relative to --data-root, $GSSLAM_DATA, data/ and ../shared/data. See docs/evaluation.md.
    """
    if compare is not None:
        from gsslam.run.batch import read_rows
        from gsslam.run.results import compare_markdown, compare_rows

        typer.echo(compare_markdown(compare_rows(read_rows(compare[0]), read_rows(compare[1]))))
        return
    if manifest is None:
        raise typer.BadParameter("give a manifest (or a suite name), or --compare A B", param_hint="MANIFEST")
    run_manifest(manifest, out, jobs, address, max_frames, data_root)
