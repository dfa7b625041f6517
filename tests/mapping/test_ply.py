"""3DGS PLY: round trip, standard layout, errors."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.io.ply import GaussianPly, PlyError, read_ply, write_ply


def _random(n: int, n_rest: int = 0) -> GaussianPly:
    rng = np.random.default_rng(0)
    q = rng.normal(size=(n, 4))
    return GaussianPly(
        means=rng.normal(size=(n, 3)),
        quats_wxyz=q / np.linalg.norm(q, axis=1, keepdims=True),
        log_scales=rng.normal(size=(n, 3)) - 4,
        opacity_logits=rng.normal(size=n),
        f_dc=rng.normal(size=(n, 3)),
        f_rest=rng.normal(size=(n, n_rest)),
    )


@pytest.mark.parametrize("n_rest", [0, 9])
def test_round_trip_is_exact(tmp_path, n_rest):
    g = _random(257, n_rest)
    size = write_ply(tmp_path / "map.ply", g)
    back = read_ply(tmp_path / "map.ply")
    assert size == (tmp_path / "map.ply").stat().st_size
    for name in ("means", "quats_wxyz", "log_scales", "opacity_logits", "f_dc", "f_rest"):
        np.testing.assert_array_equal(getattr(back, name), getattr(g, name).astype(np.float32))


def test_header_is_the_standard_3dgs_layout(tmp_path):
    write_ply(tmp_path / "m.ply", _random(3))
    raw = (tmp_path / "m.ply").read_bytes()
    header = raw[: raw.index(b"end_header\n")].decode().splitlines()
    assert header[:3] == ["ply", "format binary_little_endian 1.0", "element vertex 3"]
    props = [ln.split()[2] for ln in header if ln.startswith("property float")]
    assert props == [
        "x",
        "y",
        "z",
        "nx",
        "ny",
        "nz",
        "f_dc_0",
        "f_dc_1",
        "f_dc_2",
        "opacity",
        "scale_0",
        "scale_1",
        "scale_2",
        "rot_0",
        "rot_1",
        "rot_2",
        "rot_3",
    ]
    assert len(raw) - len(b"\n".join(h.encode() for h in header)) - len(b"\nend_header\n") == 3 * 17 * 4


def test_rgb_from_f_dc():
    g = _random(2)
    g.f_dc[:] = 0.0
    np.testing.assert_allclose(g.rgb, 0.5)


def test_errors(tmp_path):
    with pytest.raises(PlyError, match="not found"):
        read_ply(tmp_path / "missing.ply")
    (tmp_path / "a.ply").write_text("ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")
    with pytest.raises(PlyError, match="binary_little_endian"):
        read_ply(tmp_path / "a.ply")
    (tmp_path / "b.ply").write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nend_header\n\0\0\0\0"
    )
    with pytest.raises(PlyError, match="missing properties"):
        read_ply(tmp_path / "b.ply")
    with pytest.raises(PlyError):
        GaussianPly(np.zeros((2, 3)), np.zeros((2, 4)), np.zeros((2, 3)), np.zeros(3), np.zeros((2, 3)))
