"""Atomic writes: a failed or interrupted writer leaves the previous file and no temporary file."""

from __future__ import annotations

import pytest

from gsslam.io.atomic import TMP_MARK, atomic_path, atomic_write_text


@pytest.mark.parametrize("exc", [RuntimeError("disk"), KeyboardInterrupt()])
def test_interrupted_writer_keeps_the_old_file(tmp_path, exc):
    target = tmp_path / "metrics.json"
    atomic_write_text(target, '{"old": 1}')
    with pytest.raises(type(exc)):
        with atomic_path(target) as tmp:
            assert tmp.parent == tmp_path and tmp.suffix == ".json" and TMP_MARK in tmp.name
            tmp.write_text('{"new": ')  # half written when the interruption comes
            raise exc
    assert target.read_text() == '{"old": 1}'
    assert [p.name for p in tmp_path.iterdir()] == ["metrics.json"]


def test_success_replaces_and_a_writer_that_wrote_nothing_fails(tmp_path):
    target = tmp_path / "a.txt"
    atomic_write_text(target, "one")
    atomic_write_text(target, "two")
    assert target.read_text() == "two"
    with pytest.raises(FileNotFoundError, match="did not create"):
        with atomic_path(target):
            pass  # e.g. cv2.imwrite returned False
    assert target.read_text() == "two" and len(list(tmp_path.iterdir())) == 1
