"""A run's output folder: one run at a time, never mixed with the files of an older run.

- :class:`RunFolder` creates ``--out``, takes its lock and checks it. A folder that already holds
  gsslam's files (:data:`OWN_FILES`, :data:`OWN_DIRS`) is refused unless ``overwrite`` (which removes
  only those files, never anything else in the folder), or ``resume`` (the run continues from its
  checkpoint, :mod:`gsslam.run.checkpoint`, and keeps its files until it rewrites them).
- The lock is ``.gsslam.lock`` held with ``flock`` for the whole run: a second run into the same
  folder is refused while the first one lives. The kernel releases the lock when a process dies
  (even by SIGKILL), so a lock file left behind never blocks the next run.
"""

from __future__ import annotations

import errno
import fcntl
import logging
import os
import shutil
from pathlib import Path

from gsslam.errors import GsslamError
from gsslam.io.atomic import TMP_MARK

log = logging.getLogger(__name__)

OWN_FILES = (
    "config.yaml",
    "metrics.json",
    "trajectory.tum",
    "keyframes.tum",
    "trajectory_colour.tum",  # when trajectory.tum is another camera (gsslam/run/trajectory_camera.py)
    "keyframes_colour.tum",
    "trajectory.png",
    "map.ply",
    "intrinsics.yaml",
    "run.rrd",  # gsslam run --viz rerun / gsslam view
    "ate.png",  # gsslam demo
)
OWN_DIRS = ("renders", "keyframes", "export_colmap", "export_nerfstudio", "export_inria", "checkpoint")
LOCK_NAME = ".gsslam.lock"


class RunFolderError(GsslamError):
    """The output folder cannot be used: a file is in the way, it holds another run, or a run is live."""


class RunFolder:
    """``with RunFolder(out, overwrite=...) as folder:`` the folder is ours until the block ends.

    ``resume``: the folder holds the run to continue; its files are kept.
    """

    def __init__(self, path: str | Path, overwrite: bool = False, resume: bool = False) -> None:
        self.path = Path(path)
        self.overwrite = overwrite
        self.resume = resume
        self._lock_fd: int | None = None

    # ---- the folder ------------------------------------------------------------------------------

    def own_entries(self) -> list[Path]:
        """gsslam's files and folders present in the folder (leftover temporary files included)."""
        if not self.path.is_dir():
            return []
        found = [self.path / n for n in (*OWN_FILES, *OWN_DIRS) if (self.path / n).exists()]
        found += sorted(p for p in self.path.iterdir() if p.name.startswith(".") and TMP_MARK in p.name)
        return found

    def _create(self) -> None:
        for parent in [self.path, *self.path.parents]:
            if parent.exists() and not parent.is_dir():
                raise RunFolderError(
                    f"--out {self.path}: {parent} is a file, not a folder; choose another path"
                )
            if parent.exists():
                break
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise RunFolderError(f"cannot create the output folder {self.path}: {e.strerror}") from None

    def _check_previous_run(self) -> None:
        previous = self.own_entries()
        if not previous or self.resume:
            return
        for p in previous:  # generic names: never replace or remove a file gsslam did not write
            if not _written_by_gsslam(p):
                raise RunFolderError(
                    f"{p} is not a file gsslam wrote, and a run would replace it; "
                    "choose another --out (or move the file)"
                )
        names = ", ".join(p.name for p in previous[:4]) + (", ..." if len(previous) > 4 else "")
        if not self.overwrite:
            raise RunFolderError(
                f"{self.path} holds another run ({names}); choose another --out, or pass --overwrite "
                "to replace it (only gsslam's own files are removed)"
            )
        for p in previous:
            if p.is_dir():
                shutil.rmtree(p)
            else:
                p.unlink(missing_ok=True)
        log.info("--overwrite: removed the previous run's %s from %s", names, self.path)

    # ---- the lock --------------------------------------------------------------------------------

    def _acquire(self) -> None:
        lock = self.path / LOCK_NAME
        for _ in range(10):  # the holder may unlink the file between our open and our flock: retry
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as e:
                holder = _read_pid(fd)
                os.close(fd)
                who = f" (pid {holder})" if holder else ""
                if e.errno in (errno.EAGAIN, errno.EACCES):
                    raise RunFolderError(
                        f"another gsslam run{who} is writing to {self.path}; "
                        "wait for it to finish or choose another --out"
                    ) from None
                raise
            try:
                same = os.fstat(fd).st_ino == os.stat(lock).st_ino
            except FileNotFoundError:
                same = False
            if same:
                os.ftruncate(fd, 0)
                os.write(fd, f"{os.getpid()}\n".encode())
                self._lock_fd = fd
                return
            os.close(fd)
        raise RunFolderError(f"cannot take the lock {lock}; is another process using the folder?")

    def _release(self) -> None:
        if self._lock_fd is None:
            return
        try:
            (self.path / LOCK_NAME).unlink(missing_ok=True)
        finally:
            fcntl.flock(self._lock_fd, fcntl.LOCK_UN)
            os.close(self._lock_fd)
            self._lock_fd = None

    def __enter__(self) -> RunFolder:
        self._create()
        self._acquire()
        try:
            self._check_previous_run()
        except BaseException:
            self._release()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self._release()


def _written_by_gsslam(path: Path) -> bool:
    """``config.yaml`` and ``metrics.json`` are common names: check that gsslam wrote them."""
    import json

    if path.name not in ("config.yaml", "metrics.json"):
        return True
    try:
        if path.name == "metrics.json":
            data = json.loads(path.read_text(encoding="utf-8"))
            return isinstance(data, dict) and ("status" in data or "frames_posed" in data)
        from gsslam.config import Config, read_config_file

        data = read_config_file(path)
        known = {f for f in Config.__dataclass_fields__}
        return bool(data) and set(data) <= known and "mode" in data
    except (GsslamError, OSError, ValueError):
        return False


def _read_pid(fd: int) -> int | None:
    try:
        text = os.pread(fd, 32, 0).decode().strip()
        return int(text) if text else None
    except (OSError, ValueError):
        return None
