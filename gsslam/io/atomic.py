"""Files written whole or not at all: a temporary file in the same folder, then one rename.

A reader (or a run killed half-way) never sees half a file: either the previous version or the new
one. The temporary name starts with ``.`` and holds ``.tmp-``, keeps the final suffix (so OpenCV and
matplotlib pick the format from it), and is removed when the writer fails or is interrupted.
``os.replace`` is atomic within one file system, which the same folder guarantees.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

TMP_MARK = ".tmp-"  # in the name of every temporary file (run folders clean them up)


def temporary_sibling(path: str | Path) -> Path:
    """A fresh hidden name beside ``path`` with the same suffix, e.g. ``.map.tmp-1a2b3c.ply``."""
    p = Path(path)
    return p.with_name(f".{p.stem}{TMP_MARK}{os.getpid()}-{secrets.token_hex(3)}{p.suffix}")


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write to; on success it replaces ``path``, on any error (or Ctrl-C)
    it is removed and ``path`` keeps its previous content."""
    final = Path(path)
    tmp = temporary_sibling(final)
    try:
        yield tmp
        if not tmp.exists():
            raise FileNotFoundError(f"the writer did not create {tmp}")
        os.replace(tmp, final)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (flushed to disk before the rename)."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))
