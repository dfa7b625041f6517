"""Where the CPU rasterizer kernel is loaded from: installed, private cache, never a folder others can write.

The "compiler" is replaced by a copy of one real build (``kernel`` below, built once per module), so
each test exercises the loader's choices, not the compiler. The planted libraries are real shared
libraries whose constructor writes a marker file: if one were ever loaded, the marker would exist.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest
import torch

from gsslam.config import MapperConfig
from gsslam.mapping import rasterize_build as build
from gsslam.mapping import rasterize_cpu
from gsslam.mapping.mapper import GaussianMapper
from gsslam.mapping.rasterize import RasterizerUnavailableError, render, resolve_backend
from gsslam.types import CameraIntrinsics

CC = rasterize_cpu._compiler()
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler to build the test libraries")


@pytest.fixture(scope="module")
def kernel(tmp_path_factory) -> Path:
    """One real build of rasterize_cpu.c with the shared recipe."""
    if CC is None:
        pytest.skip("no C compiler")
    path = tmp_path_factory.mktemp("kernel") / "kernel.so"
    build.compile_library(CC, path)
    return path


def _plant(path: Path, marker: Path) -> Path:
    """A shared library that creates ``marker`` when it is loaded."""
    src = path.with_suffix(".c")
    src.write_text(
        "#include <stdio.h>\n"
        "__attribute__((constructor)) static void planted(void) {\n"
        f'  FILE *f = fopen("{marker}", "w"); if (f) fclose(f);\n'
        "}\n"
    )
    subprocess.run([CC, "-shared", "-fPIC", str(src), "-o", str(path)], check=True, capture_output=True)
    src.unlink()
    return path


@pytest.fixture
def fresh_loader(monkeypatch, kernel, tmp_path):
    """The loader's state reset, no installed library, a private temp dir, and a 'compiler' that copies."""
    builds = []

    def fake_compile(cc, target, source=build.SOURCE):
        builds.append(target)
        tmp = target.with_name("building.so")
        shutil.copy(kernel, tmp)
        os.chmod(tmp, 0o755)
        os.replace(tmp, target)  # like the real build: replaces whatever was at target

    monkeypatch.setattr(rasterize_cpu, "_lib", None)
    monkeypatch.setattr(rasterize_cpu, "_origin", None)
    monkeypatch.setattr(rasterize_cpu, "_failure", None)
    monkeypatch.setattr(rasterize_cpu, "_installed_library", lambda: None)
    monkeypatch.setattr(build, "compile_library", fake_compile)
    tmp = tmp_path / "systmp"
    tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    return tmp, builds


def _loaded_path() -> str:
    return rasterize_cpu._lib._name


@needs_cc
def test_library_planted_at_the_old_predictable_temp_path_is_not_loaded(fresh_loader, monkeypatch, tmp_path):
    tmp, builds = fresh_loader
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    monkeypatch.setenv("GSSLAM_CACHE_DIR", str(blocker / "cache"))  # cannot be created: temp fallback
    marker = tmp_path / "planted_was_loaded"
    old = tmp / "gsslam" / f"rasterize_cpu_{build.source_key()}.so"  # where gsslam <= 0.1 looked
    old.parent.mkdir()
    _plant(old, marker)
    old.chmod(0o777)
    old.parent.chmod(0o777)
    assert rasterize_cpu.available(torch.zeros(1))
    assert not marker.exists()
    private = tmp / f"gsslam-{os.getuid()}"
    assert Path(_loaded_path()).parent == private and builds == [Path(_loaded_path())]
    assert (private.stat().st_mode & 0o777) == 0o700
    assert rasterize_cpu.origin() == "built"


@needs_cc
def test_library_others_could_write_is_rebuilt_not_loaded(fresh_loader, monkeypatch, tmp_path):
    _, builds = fresh_loader
    cache = tmp_path / "cache"
    cache.mkdir(mode=0o777)
    cache.chmod(0o777)  # an older gsslam under a 002 umask: ours, but group/world writable
    monkeypatch.setenv("GSSLAM_CACHE_DIR", str(cache))
    marker = tmp_path / "planted_was_loaded"
    target = cache / f"rasterize_cpu_{build.source_key()}.so"
    _plant(target, marker).chmod(0o666)
    assert rasterize_cpu.available(torch.zeros(1))
    assert not marker.exists() and builds == [target] and _loaded_path() == str(target)
    assert (cache.stat().st_mode & 0o022) == 0 and (target.stat().st_mode & 0o022) == 0


@needs_cc
def test_symlinked_library_is_not_loaded(fresh_loader, monkeypatch, tmp_path):
    _, builds = fresh_loader
    monkeypatch.setenv("GSSLAM_CACHE_DIR", str(tmp_path / "cache"))
    marker = tmp_path / "planted_was_loaded"
    elsewhere = _plant(tmp_path / "elsewhere.so", marker)
    (tmp_path / "cache").mkdir(mode=0o700)
    target = tmp_path / "cache" / f"rasterize_cpu_{build.source_key()}.so"
    target.symlink_to(elsewhere)
    assert rasterize_cpu.available(torch.zeros(1))
    assert not marker.exists() and builds == [target] and not target.is_symlink()


@pytest.mark.skipif(not hasattr(os, "chown") or os.geteuid() != 0, reason="needs root to fake another owner")
def test_folder_of_another_user_is_refused(tmp_path):
    folder = tmp_path / "theirs"
    folder.mkdir(mode=0o700)
    os.chown(folder, 65534, 65534)
    with pytest.raises(build.InsecureLocationError, match="belongs to uid 65534"):
        build.private_folder(folder)


@needs_cc
def test_no_private_folder_means_no_kernel_and_a_reason(fresh_loader, monkeypatch, tmp_path):
    tmp, builds = fresh_loader
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    monkeypatch.setenv("GSSLAM_CACHE_DIR", str(blocker / "cache"))
    (tmp / f"gsslam-{os.getuid()}").write_text("squatted")  # the per-user fallback is taken
    assert not rasterize_cpu.available(torch.zeros(1)) and builds == []
    assert "no private folder" in rasterize_cpu.unavailable_reason()
    assert resolve_backend("auto", "cpu") == "torch"
    with pytest.raises(RasterizerUnavailableError, match="pip install"):
        resolve_backend("c", "cpu")


@needs_cc
def test_installed_library_is_used_without_compiling(fresh_loader, monkeypatch, kernel, tmp_path):
    _, builds = fresh_loader
    monkeypatch.setattr(rasterize_cpu, "_installed_library", lambda: kernel)
    monkeypatch.setenv("GSSLAM_CACHE_DIR", str(tmp_path / "cache"))
    assert rasterize_cpu.available(torch.zeros(1)) and rasterize_cpu.origin() == "installed"
    assert builds == [] and not (tmp_path / "cache").exists()
    assert resolve_backend("auto", "cpu") == "c"


@needs_cc
def test_installed_library_from_an_older_source_is_rebuilt(fresh_loader, monkeypatch, kernel, tmp_path):
    _, builds = fresh_loader
    monkeypatch.setattr(rasterize_cpu, "_installed_library", lambda: kernel)
    monkeypatch.setenv("GSSLAM_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(build, "source_key", lambda source=build.SOURCE: "0123456789abcdef")  # C file edited
    assert rasterize_cpu.available(torch.zeros(1)) and rasterize_cpu.origin() == "built"
    assert builds == [tmp_path / "cache" / "rasterize_cpu_0123456789abcdef.so"]


def test_c_backend_without_a_kernel_fails_loudly_and_auto_uses_torch(monkeypatch, caplog):
    monkeypatch.setattr(rasterize_cpu, "_lib", None)
    monkeypatch.setattr(rasterize_cpu, "_failure", "no C compiler found for the first-use build")
    intr = CameraIntrinsics(50.0, 50.0, 15.5, 11.5, 32, 24)
    with pytest.raises(RasterizerUnavailableError, match="no C compiler.*pip install"):
        GaussianMapper(MapperConfig(rasterizer="c", device="cpu"), intr)
    assert GaussianMapper(MapperConfig(rasterizer="auto", device="cpu"), intr).rasterizer_backend == "torch"
    assert GaussianMapper(MapperConfig(rasterizer="torch", device="cpu"), intr).rasterizer_backend == "torch"
    z = torch.zeros(1, 3)
    quat, opacity = torch.tensor([[1.0, 0, 0, 0]]), torch.ones(1) * 0.5
    args = (z, quat, z + 0.1, opacity, z, torch.eye(4), torch.eye(3), 4, 4)
    with pytest.raises(RasterizerUnavailableError, match="unavailable"):
        render(*args, backend="c")
    assert render(*args, backend="auto").color.shape == (4, 4, 3)


def test_explicit_backends_on_the_wrong_device_name_the_fix():
    with pytest.raises(RasterizerUnavailableError, match="mapper.device=cpu"):
        resolve_backend("c", "cuda")
    with pytest.raises(RasterizerUnavailableError, match="CUDA"):
        resolve_backend("gsplat", "cpu")
    assert resolve_backend("torch", "cuda") == "torch"
    with pytest.raises(Exception, match="unknown rasterizer backend"):
        resolve_backend("opengl", "cpu")
