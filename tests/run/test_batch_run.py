"""gsslam batch end to end on bundled data: in-process (no Ray), Ray local mode with a killed run and a
resume, failures recorded as rows, and --compare."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gsslam.run.batch import BatchError, BatchOptions, read_rows, run_batch
from gsslam.run.manifest import parse_manifest

REPO = Path(__file__).resolve().parents[2]
# 2 sequences x 2 configurations of the bundled teddy frames; tiny runs (12 frames, no mapper, no loops)
MANIFEST = {
    "name": "tiny",
    "defaults": {"frames": 12, "set": ["mapper.enabled=false", "loop.enabled=false"]},
    "sequences": [
        {
            "name": "teddy",
            "path": "rgbd_dataset_freiburg3_teddy_60",
            "dataset": "tum",
            "mode": ["rgbd", "mono"],
        }
    ],
    "configs": [{"name": "default"}, {"name": "kf6", "set": ["keyframes.min_flow_px=6"]}],
}
RUN_IDS = {"teddy_rgbd__default", "teddy_rgbd__kf6", "teddy_mono__default", "teddy_mono__kf6"}
SAME = (
    "status",
    "mode",
    "frames",
    "frames_posed",
    "keyframes",
    "ate_m",
    "sim3_scale",
    "rpe_t_m",
    "rpe_r_deg",
)


def _write_manifest(folder: Path) -> Path:
    import yaml

    path = folder / "tiny.yaml"
    path.write_text(yaml.safe_dump(MANIFEST, sort_keys=False))
    return path


def _table(rows: list[dict]) -> dict:
    return {(r["sequence"], r["config"]): r for r in rows}


@pytest.fixture(scope="module")
def inprocess_batch(tmp_path_factory):
    """The batch with Ray unavailable and --jobs 1: every run in this process."""
    out = tmp_path_factory.mktemp("batch_inprocess")
    manifest = parse_manifest(MANIFEST, source=_write_manifest(out))
    saved = sys.modules.get("ray")
    sys.modules["ray"] = None  # import ray -> ImportError, as without the extra
    try:
        with pytest.raises(BatchError, match=r"gsslam\[batch\]"):
            run_batch(manifest, BatchOptions(out=out / "par", jobs=2))
        t0 = time.perf_counter()
        result = run_batch(manifest, BatchOptions(out=out / "b", jobs=1))
        seconds = time.perf_counter() - t0
    finally:
        if saved is None:
            sys.modules.pop("ray", None)
        else:
            sys.modules["ray"] = saved
    return result, seconds


def test_inprocess_batch_without_ray_is_complete(inprocess_batch):
    result, _ = inprocess_batch
    assert set(result.executed) == RUN_IDS and result.reused == []
    rows = _table(result.rows)
    assert all(r["status"] == "ok" for r in rows.values())
    for (seq, _), r in rows.items():
        assert r["frames"] == 12 and r["frames_posed"] == 12
        assert r["ate_m"] < 0.01  # measured 0.2 cm (rgbd), 0.2 cm (mono, Sim(3))
        assert 0 < r["rpe_t_m"] < 0.01 and r["rpe_r_deg"] < 1.0
        assert 0.5 < r["sim3_scale"] < 1.5 and r["t_rel_pct"] is None  # not KITTI
        assert r["align"] == ("sim3" if seq == "teddy_mono" else "se3")
    out = result.out
    for name in ("results.md", "results.csv", "results.json", "ate.png", "manifest.yaml"):
        assert (out / name).is_file(), name
    md = (out / "results.md").read_text()
    assert md.count("| teddy_") == 4 and "| default | 2 / 2 |" in md and "| kf6 | 2 / 2 |" in md
    # a second call finds every run complete and runs nothing
    again = run_batch(parse_manifest(MANIFEST, source=out / "manifest.yaml"), BatchOptions(out=out, jobs=1))
    assert again.executed == [] and set(again.reused) == RUN_IDS


def test_failed_and_missing_runs_are_rows_and_the_batch_goes_on(tmp_path):
    m = parse_manifest({
        "sequences": [
            {"name": "teddy", "path": "rgbd_dataset_freiburg3_teddy_60", "mode": "rgbd", "frames": 5},
            {"name": "absent", "path": "no_such_sequence_anywhere"},
        ],
        "configs": [{"name": "bad", "set": ["mapper.no_such_key=1"]}],
    })  # fmt: skip
    result = run_batch(m, BatchOptions(out=tmp_path))
    rows = _table(result.rows)
    assert rows[("teddy", "bad")]["status"] == "failed"
    assert "unknown config key 'mapper.no_such_key'" in rows[("teddy", "bad")]["error"]
    assert rows[("absent", "bad")]["status"] == "skipped"
    assert "data not found: no_such_sequence_anywhere" in rows[("absent", "bad")]["error"]
    rec = json.loads((tmp_path / "runs" / "teddy__bad" / "result.json").read_text())
    assert "Traceback" in rec["traceback"]
    assert "Runs not finished" in (tmp_path / "results.md").read_text()


def _batch_cmd(manifest: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "gsslam", "batch", str(manifest), "--jobs", "2", "--out", str(out)]


def _kill_one_run_midway(proc: subprocess.Popen, out: Path, timeout: float = 240.0) -> str:
    """SIGKILL the worker of the first run seen between its first and last frame; its run id."""
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end and proc.poll() is None:
        for status in sorted(out.glob("runs/*/status.json")):
            try:
                s = json.loads(status.read_text())
            except ValueError:
                continue
            if s["state"] == "running" and 1 <= s["frames_done"] < s.get("frames_total", 12):
                assert s["pid"] != proc.pid  # a Ray worker process, not the batch driver
                os.kill(s["pid"], signal.SIGKILL)
                return status.parent.name
        time.sleep(0.05)
    raise AssertionError("no run was seen mid-way")


def test_ray_local_kill_a_run_then_resume(tmp_path, inprocess_batch):
    pytest.importorskip("ray")
    manifest = _write_manifest(tmp_path)
    out = tmp_path / "b"
    env = {**os.environ, "PYTHONPATH": f"{REPO}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    t0 = time.perf_counter()
    proc = subprocess.Popen(_batch_cmd(manifest, out), env=env, cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)  # fmt: skip
    killed = _kill_one_run_midway(proc, out)
    log, _ = proc.communicate(timeout=300)
    assert proc.returncode == 0, log
    first = _table(read_rows(out))
    failed = [k for k, r in first.items() if r["status"] != "ok"]
    assert failed == [tuple(killed.split("__"))], log
    assert first[failed[0]]["error"].startswith("worker died"), first[failed[0]]["error"]
    done_before = {p.parent.name: p.stat().st_mtime_ns for p in out.glob("runs/*/result.json")}

    second = subprocess.run(_batch_cmd(manifest, out), env=env, cwd=tmp_path, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    assert second.returncode == 0, second.stdout + second.stderr
    summary = json.loads((out / "results.json").read_text())
    assert summary["executed"] == [killed] and set(summary["reused"]) == RUN_IDS - {killed}
    for run_id, mtime in done_before.items():  # finished runs were not touched
        if run_id != killed:
            assert (out / "runs" / run_id / "result.json").stat().st_mtime_ns == mtime
    rows = _table(summary["rows"])
    assert all(r["status"] == "ok" for r in rows.values()) and len(rows) == 4
    pids = {r["pid"] for r in rows.values()}
    assert len(pids) == 4  # each run in a process of its own
    # the same table as without Ray (one thread per run vs the test process's threads)
    ref = _table(inprocess_batch[0].rows)
    for key, r in rows.items():
        for col in SAME:
            assert r[col] == pytest.approx(ref[key][col], rel=1e-6, abs=1e-9), (key, col)
    print(f"ray batch with a kill and a resume: {seconds:.1f} s")


def test_cli_compare_prints_differences(inprocess_batch, tmp_path):
    from typer.testing import CliRunner

    from gsslam.cli import app

    a = inprocess_batch[0].out
    data = json.loads((a / "results.json").read_text())
    for r in data["rows"]:
        r["ate_m"] += 0.01  # B is 1 cm worse everywhere
    (tmp_path / "results.json").write_text(json.dumps(data))
    res = CliRunner().invoke(app, ["batch", "--compare", str(a), str(tmp_path)])
    assert res.exit_code == 0, res.output
    lines = [ln for ln in res.output.splitlines() if ln.startswith("| teddy_")]
    assert len(lines) == 4 and all("| +1.00 |" in ln for ln in lines)
