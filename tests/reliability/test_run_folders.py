"""Run folders: an older run is never mixed with a new one, one run at a time, a killed run leaves
whole files only, and SIGTERM is handled like Ctrl-C (issue #14)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
from reliability_helpers import (
    EXIT_SIGTERM,
    REPO,
    assert_error,
    gsslam,
    snapshot,
    teddy_copy,
)

from gsslam.io.atomic import TMP_MARK
from gsslam.run.folder import LOCK_NAME, RunFolder

FAST = ("--set", "mapper.enabled=false", "--set", "loop.enabled=false", "--no-progress")


def _metrics(out):
    return json.loads((out / "metrics.json").read_text())


def _old_run(out):
    """The files an older run with a map left behind, and a file of the user's."""
    from gsslam.config import Config, save_config

    (out / "renders").mkdir(parents=True)
    (out / "renders" / "kf_0.png").write_bytes(b"old panel")
    for name in ("map.ply", "intrinsics.yaml", "trajectory.tum"):
        (out / name).write_text(f"old {name}\n")
    save_config(Config(), out / "config.yaml")
    (out / "metrics.json").write_text(json.dumps({"frames_posed": 40, "mapper": {"psnr_keyframes": 25.0}}))
    (out / ".trajectory.tum.tmp-1-abc.tum").write_text("half")  # a killed run's leftover
    (out / "notes.txt").write_text("the user's notes\n")


def test_a_folder_holding_another_run_is_refused_then_overwritten(tmp_path):
    seq = teddy_copy(tmp_path, n=8)
    out = tmp_path / "out"
    _old_run(out)
    before = snapshot(out)
    r = gsslam("run", seq, "--out", out, *FAST)
    assert_error(r, f"{out} holds another run", "--overwrite", "only gsslam's own files")
    assert snapshot(out) == before  # nothing of the older run (or the user's) touched
    r = gsslam("run", seq, "--out", out, "--overwrite", *FAST)
    assert r.returncode == 0, r.stderr
    names = {p.name for p in out.iterdir()}
    # the stale map and panels are gone; the user's file stays; no lock, no temporary file
    assert names >= {"config.yaml", "keyframes.tum", "metrics.json", "notes.txt", "trajectory.tum"}
    assert not names & {"map.ply", "renders", LOCK_NAME} and not [n for n in names if TMP_MARK in n]
    assert (out / "notes.txt").read_text() == "the user's notes\n"
    m = _metrics(out)
    assert m["status"] == "complete" and m["mapper"] is None and m["interrupted"] is False
    prov = m["provenance"]
    assert prov["command"][:2] == ["gsslam", "run"] and "--overwrite" in prov["command"]
    assert prov["dataset_path"] == str(seq.resolve()) and len(prov["config_sha256"]) == 64
    assert prov["gsslam_version"] and prov["versions"]["gtsam"] and prov["versions"]["opencv"]
    assert prov["rasterizer"] is None  # no map, no rasterizer
    # the older run's map is gone, so `gsslam render` cannot render it along the new trajectory
    assert_error(gsslam("render", out, "--out", tmp_path / "r"), "map.ply", "not found")


def test_files_gsslam_did_not_write_are_never_replaced(tmp_path):
    seq = teddy_copy(tmp_path, n=4)
    out = tmp_path / "out"
    out.mkdir()
    (out / "config.yaml").write_text("camera: my own settings\n")
    before = snapshot(out)
    for extra in ((), ("--overwrite",)):
        r = gsslam("run", seq, "--out", out, *FAST, *extra)
        assert_error(r, f"{out / 'config.yaml'} is not a file gsslam wrote", "choose another --out")
        assert snapshot(out) == before


def test_a_second_run_into_a_live_folder_is_refused(tmp_path):
    seq = teddy_copy(tmp_path, n=4)
    out = tmp_path / "out"
    with RunFolder(out):  # this process holds the folder, as a running `gsslam run` does
        r = gsslam("run", seq, "--out", out, *FAST)
        assert_error(r, f"another gsslam run (pid {os.getpid()}) is writing to {out}", "choose another --out")
        assert [p.name for p in out.iterdir()] == [LOCK_NAME]
    assert not (out / LOCK_NAME).exists()
    # a lock file left by a killed run (nobody holds it) does not block
    (out / LOCK_NAME).write_text("12345\n")
    with RunFolder(out):
        pass


def test_out_that_is_a_file_or_under_a_file(tmp_path):
    seq = teddy_copy(tmp_path, n=4)
    f = tmp_path / "notes.txt"
    f.write_text("my notes\n")
    assert_error(gsslam("run", seq, "--out", f, *FAST), f"--out {f}: {f} is a file")
    assert_error(gsslam("run", seq, "--out", f / "run", *FAST), f"{f} is a file, not a folder")
    assert f.read_text() == "my notes\n"


def _start(seq, out, *extra):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    args = [sys.executable, "-m", "gsslam", "run", str(seq), "--out", str(out), *FAST, *extra]
    return subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_frames(out, proc, timeout=120.0):
    """Until the run has started tracking (metrics.json says running, plus a moment)."""
    t0 = time.monotonic()
    while not (out / "metrics.json").exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() - t0 < timeout
        time.sleep(0.2)
    time.sleep(2.0)


def test_sigterm_is_handled_like_ctrl_c(tmp_path):
    seq = teddy_copy(tmp_path, n=60)
    out = tmp_path / "out"
    proc = _start(seq, out)
    _wait_for_frames(out, proc)
    if proc.poll() is not None:
        pytest.skip("the run finished before the signal (a very fast machine)")
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == EXIT_SIGTERM, err
    assert "Traceback" not in err and err.strip().splitlines()[-1] == "interrupted"
    m = _metrics(out)
    assert m["status"] == "complete" and m["interrupted"] is True
    assert 0 < m["frames"] < 60
    assert (out / "trajectory.tum").is_file() and not (out / LOCK_NAME).exists()


def test_sigkill_leaves_only_whole_files(tmp_path):
    """Killed at a random moment: every file there is whole, and the folder is refused until --overwrite."""
    seq = teddy_copy(tmp_path, n=60)
    out = tmp_path / "out"
    proc = _start(seq, out)
    _wait_for_frames(out, proc)
    time.sleep(float(os.urandom(1)[0]) / 255 * 3.0)
    proc.kill()
    proc.communicate(timeout=60)
    m = _metrics(out)  # whole JSON, never half
    assert m["status"] in ("running", "partial", "complete")
    visible = [p for p in out.iterdir() if not p.name.startswith(".")]
    assert {p.name for p in visible} >= {"config.yaml", "metrics.json"}
    r = gsslam("run", seq, "--out", out, "--max-frames", "4", *FAST)
    assert_error(r, "holds another run")
    r = gsslam("run", seq, "--out", out, "--max-frames", "4", "--overwrite", *FAST)
    assert r.returncode == 0, r.stderr
    assert not [p for p in out.iterdir() if TMP_MARK in p.name or p.name == LOCK_NAME]
    assert _metrics(out)["frames"] == 4


def test_a_second_interrupt_while_the_map_is_written_keeps_the_finished_files(tmp_path, monkeypatch):
    """Ctrl-C during the slow map outputs: trajectory and metrics (marked partial) are already on disk."""
    from gsslam.config import load_config
    from gsslam.datasets.synthetic import SyntheticDataset
    from gsslam.run import outputs
    from gsslam.run.sequence import run_dataset

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(outputs, "write_map_outputs", interrupted)
    ds = SyntheticDataset(n_frames=10, width=160, height=120, trajectory="orbit", arc_deg=30, seed=1)
    over = ["loop.enabled=false", "mapper.iterations=1", "mapper.max_side=48",
            "mapper.final_iterations_per_keyframe=0"]  # fmt: skip
    with pytest.raises(KeyboardInterrupt):
        run_dataset(ds, load_config(None, over, mode="rgbd"), tmp_path / "out")
    m = _metrics(tmp_path / "out")
    assert m["status"] == "partial" and m["frames"] == 10 and m["frames_posed"] >= 8
    assert m["mapper"]["status"].startswith("pending")
    assert (tmp_path / "out" / "trajectory.tum").is_file()
    assert not [p for p in (tmp_path / "out").iterdir() if TMP_MARK in p.name or p.name == LOCK_NAME]
