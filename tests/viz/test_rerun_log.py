"""A rerun recording of a run folder, read back with rerun's own RRD reader."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.io.ply import read_ply
from gsslam.io.trajectory import read_tum
from helpers.run_folder import make_run

pytest.importorskip("rerun", reason="rerun-sdk (extra 'viz', in dev) writes and reads the recording")
from rerun.chunk import RrdReader  # noqa: E402

from gsslam.viz.rerun_log import record_run  # noqa: E402


def _columns(chunks, entity: str, column: str) -> tuple[list, list]:
    """(values of ``column``, ``frame`` index per row) over the chunks of ``entity``."""
    vals, frames = [], []
    for c in chunks:
        if c.entity_path != entity:
            continue
        rb = c.to_record_batch()
        if column not in rb.schema.names:  # one entity's archetypes may sit in separate chunks
            continue
        vals += rb.column(column).to_pylist()
        frames += rb.column("frame").to_pylist() if "frame" in rb.schema.names else [None] * rb.num_rows
    return vals, frames


def test_recording_holds_trajectory_keyframes_and_map(tmp_path):
    run = make_run(tmp_path / "run", n_kf=4, n_points=300)
    (run / "metrics.json").write_text('{"events": [{"frame": 2, "kind": "lost", "detail": "x"}]}')
    rrd = record_run(run, tmp_path / "run.rrd")
    chunks = list(RrdReader(rrd).stream())
    entities = {c.entity_path for c in chunks}
    assert {"/world/trajectory", "/world/camera", "/world/map/gaussians", "/world/map/points"} <= entities
    assert {f"/world/keyframes/{k}" for k in range(4)} <= entities
    assert {"/metrics/step_translation", "/log/events", "/summary"} <= entities

    traj = read_tum(run / "trajectory.tum")
    t, frames = _columns([c for c in chunks if not c.is_static], "/world/camera", "Transform3D:translation")
    order = np.argsort(frames)
    np.testing.assert_allclose(np.array([t[k][0] for k in order]), traj.positions, rtol=1e-6)
    g = read_ply(run / "map.ply")
    centers, _ = _columns(chunks, "/world/map/gaussians", "Ellipsoids3D:centers")
    np.testing.assert_allclose(np.array(centers[0]), g.means, rtol=1e-6)
    blobs, _ = _columns(chunks, "/world/keyframes/0", "EncodedImage:blob")
    assert len(blobs) == 1 and bytes(blobs[0][0][:2]) == b"\xff\xd8"  # the keyframe's JPEG
    steps, _ = _columns(chunks, "/metrics/step_translation", "Scalars:scalars")
    d = np.linalg.norm(np.diff(traj.positions, axis=0), axis=1)
    np.testing.assert_allclose(sorted(s[0] for s in steps), sorted(d), rtol=1e-9)


def test_cli_view_writes_the_recording(tmp_path):
    from typer.testing import CliRunner

    from gsslam.cli import app

    run = make_run(tmp_path / "run", n_kf=3, n_points=20)
    res = CliRunner().invoke(app, ["view", str(run), "--no-spawn"])
    assert res.exit_code == 0, res.output
    assert (run / "run.rrd").stat().st_size > 0
