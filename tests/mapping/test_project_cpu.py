"""The C projection (rasterize_cpu.project_cpu) against its torch twin (projection.project_gaussians)."""

from __future__ import annotations

import pytest
import torch
from test_rasterize_reference import intrinsics, small_pose

from gsslam.mapping import rasterize_cpu
from gsslam.mapping.projection import project_gaussians
from gsslam.mapping.rasterize_cpu import project_cpu

pytestmark = pytest.mark.skipif(
    not rasterize_cpu.available(torch.zeros(1)), reason="no compiled C kernel (no C compiler)"
)

NAMES = ("means2d", "cov2d", "conics", "depths", "normals")


def _wide_scene(n: int, seed: int, dtype):
    """Centres from behind the camera to far off the image (the x/z clamp), random rotations."""
    g = torch.Generator().manual_seed(seed)
    lo, span = torch.tensor([-8.0, -6.0, -1.0], dtype=dtype), torch.tensor([16.0, 12.0, 6.0], dtype=dtype)
    means = torch.rand(n, 3, generator=g, dtype=dtype) * span + lo
    quats = torch.randn(n, 4, generator=g, dtype=dtype)
    scales = torch.rand(n, 3, generator=g, dtype=dtype) * 0.25 + 0.01
    return means, quats, scales


def _outputs_and_grads(fn, scene, T, K, w, h, weights, low_pass):
    ins = [t.clone().requires_grad_(True) for t in (*scene, T)]
    p = fn(ins[0], ins[1], ins[2], ins[3], K, w, h, low_pass=low_pass)
    outs = [getattr(p, name) for name in NAMES]
    sum((o * wt).sum() for o, wt in zip(outs, weights)).backward()
    return [o.detach() for o in outs], p.radii, [t.grad for t in ins]


@pytest.mark.parametrize(
    ("dtype", "rtol", "low_pass"),
    # low_pass 0: needles reach the determinant's clamp (float64 only: in float32 the determinant of a
    # needle near the camera is rounding noise above the clamp, in either implementation)
    [(torch.float64, 1e-13, 0.3), (torch.float32, 3e-6, 0.3), (torch.float64, 1e-13, 0.0)],
)
def test_c_projection_matches_torch_values_and_gradients(dtype, rtol, low_pass):
    # measured: <= 2.7e-15 (float64) and <= 8.3e-7 (float32) relative to each output's largest value
    w, h, n = 64, 48, 600
    means, quats, scales = _wide_scene(n, seed=1, dtype=dtype)
    if low_pass == 0.0:
        scales[: n // 4] = torch.tensor([1e-4, 0.0, 0.0], dtype=dtype)  # det(cov2d) 0 (+- 1e-20): clamped
    T, K = small_pose(1, dtype=dtype), intrinsics(w, h, dtype=dtype)
    g = torch.Generator().manual_seed(2)
    weights = [torch.randn(s, generator=g, dtype=dtype) for s in ((n, 2), (n, 2, 2), (n, 3), (n,), (n, 3))]
    ref = _outputs_and_grads(project_gaussians, (means, quats, scales), T, K, w, h, weights, low_pass)
    got = _outputs_and_grads(project_cpu, (means, quats, scales), T, K, w, h, weights, low_pass)
    z = means @ T[:3, :3].T + T[:3, 3]
    assert int((z[:, 2] < 0.01).sum()) > 20 and int((ref[1] > 0).sum()) > 10  # behind, and drawn
    assert int((ref[1] == 0).sum()) > 100  # off the image: the clamp of x/z is exercised
    assert torch.equal(got[1], ref[1])
    for name, a, b in zip(NAMES, got[0], ref[0]):
        scale = float(b.abs().max())
        torch.testing.assert_close(a, b, rtol=0, atol=rtol * scale, msg=lambda m, n=name: f"{n}: {m}")
    for name, a, b in zip(("means", "quats", "scales", "T_cam_world"), got[2], ref[2]):
        scale = float(b.abs().max())
        assert scale > 0, f"reference gradient of {name} is zero: the test would be vacuous"
        torch.testing.assert_close(a, b, rtol=0, atol=rtol * scale, msg=lambda m, n=name: f"{n}: {m}")


def test_c_projection_gradcheck_float64():
    w, h = 32, 24
    means, quats, scales = _wide_scene(6, seed=4, dtype=torch.float64)
    means[:, 2] = means[:, 2].abs() + 1.0  # in front, some clamped sideways
    T, K = small_pose(4), intrinsics(w, h)
    weights = [torch.rand(s, dtype=torch.float64) for s in ((6, 2), (6, 2, 2), (6, 3), (6,), (6, 3))]

    def f(means, quats, scales, T):
        p = project_cpu(means, quats, scales, T, K, w, h)
        return sum((getattr(p, name) * wt).sum() for name, wt in zip(NAMES, weights))

    inputs = tuple(t.clone().requires_grad_(True) for t in (means, quats, scales, T))
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)
