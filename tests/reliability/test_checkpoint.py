"""Checkpoint and resume (issue #14): a run SIGKILLed at a random moment and resumed gives the
uninterrupted run's trajectory and PSNR; a checkpoint of another config, a corrupt one and one with
a pickle planted in it are refused with one line and exit 2."""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from reliability_helpers import BUNDLED_TUM, EXIT_USAGE, REPO, assert_error, gsslam

from gsslam.run.checkpoint import CHECKPOINT_DIR, LATEST

# 40 frames of teddy, RGB-D, a small map: ~7 submaps, a checkpoint after each one
RUN = (
    "run", BUNDLED_TUM, "--mode", "rgbd", "--max-frames", "40", "--no-progress",
    "--set", "mapper.iterations=10", "--set", "mapper.max_side=80", "--set", "mapper.pose_iterations=5",
    "--set", "mapper.final_iterations_per_keyframe=2", "--set", "run.checkpoint_every=1",
)  # fmt: skip
FAST = (
    "run", BUNDLED_TUM, "--mode", "rgbd", "--max-frames", "40", "--no-progress",
    "--set", "mapper.enabled=false", "--set", "run.checkpoint_every=1",
)  # fmt: skip  # 40 frames: the first checkpoint (frame ~18) is well before the end


def _trajectory(out: Path) -> np.ndarray:  # [N, 8] timestamp x y z qx qy qz qw
    return np.loadtxt(out / "trajectory.tum", ndmin=2)


def _metrics(out: Path) -> dict:
    return json.loads((out / "metrics.json").read_text())


def _latest(out: Path) -> Path:
    return out / CHECKPOINT_DIR / json.loads((out / CHECKPOINT_DIR / LATEST).read_text())["name"]


def _killed_after_checkpoint(out: Path, args, delay_s: float, timeout: float = 600) -> None:
    """Start the run, wait for its first complete checkpoint, wait ``delay_s`` more, SIGKILL it."""
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "gsslam", *map(str, args), "--out", str(out)],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        t0 = time.monotonic()
        while not (out / CHECKPOINT_DIR / LATEST).exists():
            assert proc.poll() is None, "the run ended before its first checkpoint"
            assert time.monotonic() - t0 < timeout, "no checkpoint appeared"
            time.sleep(0.05)
        time.sleep(delay_s)
        assert proc.poll() is None, "the run finished before it could be killed; shorten the delay"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.slow
def test_sigkill_then_resume_gives_the_uninterrupted_run(tmp_path):
    full, killed = tmp_path / "full", tmp_path / "killed"
    r = gsslam(*RUN, "--out", full, timeout=900)
    assert r.returncode == 0, r.stderr
    assert not (full / CHECKPOINT_DIR).exists()  # a finished run removes its checkpoint

    delay = np.random.default_rng(14).uniform(0.0, 3.0)  # seeded: the same moment on every run
    _killed_after_checkpoint(killed, RUN, delay)
    at = json.loads((_latest(killed) / "manifest.json").read_text())["position"]["next_frame"]
    assert 0 < at < 40

    r = gsslam(*RUN, "--out", killed, "--resume", timeout=900)
    assert r.returncode == 0, r.stderr
    a, b = _trajectory(full), _trajectory(killed)
    assert a.shape == b.shape and len(a) >= 30  # 36 of 40 frames posed (measured)
    np.testing.assert_array_equal(a[:, 0], b[:, 0])
    assert np.abs(a[:, 1:4] - b[:, 1:4]).max() <= 1e-6  # measured: 0 (identical)
    ma, mb = _metrics(full), _metrics(killed)
    for key in ("psnr_keyframes", "psnr_other", "psnr_keyframes_native"):
        assert abs(ma["mapper"][key] - mb["mapper"][key]) <= 0.1, key
    assert (
        mb["resumed_from_frame"] >= at and mb["provenance"]["resumed_from_frame"] == mb["resumed_from_frame"]
    )
    assert mb["frames"] == ma["frames"] == 40
    assert not (killed / CHECKPOINT_DIR).exists()


@pytest.fixture(scope="module")
def interrupted(tmp_path_factory) -> Path:
    """A map-less run SIGTERMed after its first checkpoint: it writes one more and exits 143."""
    out = tmp_path_factory.mktemp("ck") / "run"
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "gsslam", *map(str, FAST), "--out", str(out)],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    t0 = time.monotonic()
    while not (out / CHECKPOINT_DIR / LATEST).exists() and proc.poll() is None:
        assert time.monotonic() - t0 < 300
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 143, err
    assert _metrics(out)["interrupted"] is True
    assert _metrics(out)["checkpoints"]["last"] == _latest(out).name
    return out


def _copy(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst


def test_resume_of_the_sigterm_checkpoint_finishes(interrupted, tmp_path):
    out = _copy(interrupted, tmp_path / "run")
    r = gsslam(*FAST, "--out", out, "--resume")
    assert r.returncode == 0, r.stderr
    m = _metrics(out)
    assert m["frames"] == 40 and m["resumed_from_frame"] > 0 and m["interrupted"] is False


def test_resume_with_another_config_is_refused(interrupted, tmp_path):
    out = _copy(interrupted, tmp_path / "run")
    r = gsslam(*FAST, "--set", "pipeline.track_points=500", "--out", out, "--resume")
    assert_error(r, "another config", code=EXIT_USAGE)
    # how often to checkpoint is not part of the run: that may change
    r = gsslam(*FAST, "--set", "run.checkpoint_every=3", "--out", out, "--resume")
    assert r.returncode == 0, r.stderr


def test_resume_without_checkpoint_is_refused(tmp_path):
    r = gsslam(*FAST, "--out", tmp_path / "empty", "--resume")
    assert_error(r, "no checkpoint", code=EXIT_USAGE)


def test_corrupt_checkpoint_is_refused(interrupted, tmp_path):
    out = _copy(interrupted, tmp_path / "run")
    arrays = _latest(out) / "arrays.npz"
    data = bytearray(arrays.read_bytes())
    data[len(data) // 2] ^= 0xFF
    arrays.write_bytes(bytes(data))
    r = gsslam(*FAST, "--out", out, "--resume")
    assert_error(r, "corrupt", "arrays.npz", code=EXIT_USAGE)


def test_other_version_is_refused(interrupted, tmp_path):
    out = _copy(interrupted, tmp_path / "run")
    mf = _latest(out) / "manifest.json"
    m = json.loads(mf.read_text())
    m["version"] = 99
    mf.write_text(json.dumps(m))
    r = gsslam(*FAST, "--out", out, "--resume")
    assert_error(r, "version 99", code=EXIT_USAGE)


class _Boom:
    def __reduce__(self):
        return (os.system, ("touch PWNED",))


def test_planted_pickle_is_never_loaded(interrupted, tmp_path):
    """A pickle in place of the arrays, with the manifest's hash updated to match: refused, not run."""
    out = _copy(interrupted, tmp_path / "run")
    folder = _latest(out)
    arrays = folder / "arrays.npz"
    np.save(arrays.with_suffix(".npy"), np.array([_Boom()], dtype=object), allow_pickle=True)
    arrays.with_suffix(".npy").replace(arrays)
    (tmp_path / "raw.pkl").write_bytes(pickle.dumps(_Boom()))
    mf = folder / "manifest.json"
    m = json.loads(mf.read_text())
    m["files"]["arrays.npz"] = hashlib.sha256(arrays.read_bytes()).hexdigest()
    mf.write_text(json.dumps(m))
    r = gsslam(*FAST, "--out", out, "--resume", cwd=tmp_path)
    assert_error(r, "cannot be read", code=EXIT_USAGE)
    assert not (tmp_path / "PWNED").exists()
    # the same with a raw pickle stream
    arrays.write_bytes((tmp_path / "raw.pkl").read_bytes())
    m["files"]["arrays.npz"] = hashlib.sha256(arrays.read_bytes()).hexdigest()
    mf.write_text(json.dumps(m))
    r = gsslam(*FAST, "--out", out, "--resume", cwd=tmp_path)
    assert_error(r, "cannot be read", code=EXIT_USAGE)
    assert not (tmp_path / "PWNED").exists()


def test_state_naming_a_foreign_class_is_refused(interrupted, tmp_path):
    """state.json may only name the registered classes: ``os.system`` & co. are never looked up."""
    out = _copy(interrupted, tmp_path / "run")
    folder = _latest(out)
    st = folder / "state.json"
    text = st.read_text().replace('"cls":"gsslam.slam.chains.Chain"', '"cls":"os.system"', 1)
    assert "os.system" in text
    st.write_text(text)
    mf = folder / "manifest.json"
    m = json.loads(mf.read_text())
    m["files"]["state.json"] = hashlib.sha256(st.read_bytes()).hexdigest()
    mf.write_text(json.dumps(m))
    r = gsslam(*FAST, "--out", out, "--resume")
    assert_error(r, "not allowed", code=EXIT_USAGE)


def test_malformed_manifest_is_refused(interrupted, tmp_path):
    out = _copy(interrupted, tmp_path / "run")
    mf = _latest(out) / "manifest.json"
    m = json.loads(mf.read_text())
    m["files"] = ["state.json"]
    mf.write_text(json.dumps(m))
    assert_error(gsslam(*FAST, "--out", out, "--resume"), "malformed", code=EXIT_USAGE)
