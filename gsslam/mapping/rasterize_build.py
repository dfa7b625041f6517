"""How the CPU rasterizer kernel ``rasterize_cpu.c`` becomes a shared library, and where it may live.

One recipe for both builds: ``setup.py`` compiles it at install time (the library then sits next to
this file as ``_rasterize_cpu<EXT_SUFFIX>``), and :mod:`gsslam.mapping.rasterize_cpu` compiles it at
first use into a private cache folder when no installed library matches the source (an editable
checkout whose C file was edited, or an install without a compiler at hand).

The library is loaded with ctypes, so whoever can write the file it is loaded from runs code in our
process. The first-use build therefore only loads from a folder that nobody else can write:
:func:`private_folder` creates it 0700, checks that it is ours and tightens it, and
:func:`library_problem` rejects a library file that is a symlink, not ours or writable by others.

Standard library only: setup.py loads this file by path, before gsslam's dependencies exist.
"""

from __future__ import annotations

import hashlib
import os
import stat
import subprocess
import tempfile
from pathlib import Path

SOURCE = Path(__file__).with_name("rasterize_cpu.c")
EXT_NAME = "gsslam.mapping._rasterize_cpu"  # the install-time build (setup.py)
CFLAGS = ("-O3", "-fPIC", "-std=gnu99", "-ffp-contract=off", "-pthread")
LDFLAGS = ("-pthread",)
LIBRARIES = ("m",)
VARIANTS = (("f32", "float", "expf"), ("f64", "double", "exp"))  # (TAG, REAL, EXP) per build of the file


class InsecureLocationError(OSError):
    """A cache folder or library that another user could write: never loaded from."""


def source_key(source: Path = SOURCE) -> str:
    """Hash of the C source and the flags; built into the library as ``gsslam_source_key_f32()``."""
    return hashlib.sha256(source.read_bytes() + " ".join(CFLAGS).encode()).hexdigest()[:16]


def macros(tag: str, real: str, exp: str, key: str) -> list[tuple[str, str]]:
    """Preprocessor definitions of one variant (``-DNAME=VALUE``)."""
    return [("REAL", real), ("TAG", tag), ("EXP", exp), ("GSSLAM_SOURCE_KEY", f'"{key}"')]


def compile_library(cc: str, target: Path, source: Path = SOURCE) -> None:
    """Compile ``source`` with the C compiler ``cc`` into ``target`` (atomically, mode 0755).

    Raises :class:`subprocess.CalledProcessError` (with the compiler's stderr) when it fails.
    """
    key = source_key(source)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        objs = []
        for tag, real, exp in VARIANTS:
            obj = Path(tmp) / f"{tag}.o"
            defs = [f"-D{name}={value}" for name, value in macros(tag, real, exp, key)]
            subprocess.run(
                [cc, *CFLAGS, *defs, "-c", str(source), "-o", str(obj)],
                check=True,
                capture_output=True,
                text=True,
            )
            objs.append(str(obj))
        out = Path(tmp) / target.name
        subprocess.run(
            [cc, "-shared", *LDFLAGS, *objs, "-o", str(out), *(f"-l{lib}" for lib in LIBRARIES)],
            check=True,
            capture_output=True,
            text=True,
        )
        os.chmod(out, 0o755)  # whatever the umask: never group/world writable
        os.replace(out, target)  # atomic: concurrent builders never see a half-written library


def _uid() -> int | None:
    return os.getuid() if hasattr(os, "getuid") else None


def private_folder(path: Path) -> Path:
    """Create ``path`` (mode 0700) if needed and make sure only we can write it; returns it.

    Raises :class:`InsecureLocationError` when it is not a folder or belongs to another user (then
    it may hold anything), ``OSError`` when it cannot be created. A folder of ours that the group
    or others may write (made by an older gsslam under a 002 umask) is tightened to drop those bits.
    """
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    st = os.stat(path)
    if not stat.S_ISDIR(st.st_mode):
        raise InsecureLocationError(f"{path} is not a folder")
    uid = _uid()
    if uid is None:  # no POSIX owners (Windows): the per-user cache folder is private already
        return path
    if st.st_uid != uid:
        raise InsecureLocationError(f"{path} belongs to uid {st.st_uid}, not to us (uid {uid})")
    if st.st_mode & 0o022:
        os.chmod(path, stat.S_IMODE(st.st_mode) & ~0o022)
        if os.stat(path).st_mode & 0o022:
            raise InsecureLocationError(f"{path} is writable by other users and could not be tightened")
    return path


def library_problem(path: Path) -> str | None:
    """Why the library file at ``path`` must not be loaded, or None when it is safe (ours, private)."""
    st = os.lstat(path)
    if not stat.S_ISREG(st.st_mode):
        return "not a regular file (a symlink?)"
    uid = _uid()
    if uid is not None and st.st_uid != uid:
        return f"owned by uid {st.st_uid}, not by us (uid {uid})"
    if st.st_mode & 0o022:
        return "writable by other users"
    return None


def cache_folders() -> list[Path]:
    """Where the first-use build may go, in order: the user's cache, then a per-user temp folder.

    The cache is ``$GSSLAM_CACHE_DIR``, else ``$XDG_CACHE_HOME/gsslam``, else ``~/.cache/gsslam``;
    the fallback ``<tmp>/gsslam-<uid>`` is used only when it passes :func:`private_folder`.
    """
    if os.environ.get("GSSLAM_CACHE_DIR"):
        first = Path(os.environ["GSSLAM_CACHE_DIR"])
    else:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        first = Path(base) / "gsslam"
    uid = _uid()
    if uid is None:
        return [first]
    return [first, Path(tempfile.gettempdir()) / f"gsslam-{uid}"]
