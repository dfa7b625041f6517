"""``gsslam bench raster``: forward and forward+backward time of the Gaussian rasterizer.

The scene is realistic: Gaussians seeded from the depth map of the first frame of the bundled TUM
fr3/teddy sequence (at the benchmark resolution), coloured from its image, with random rotations,
per-axis scales whose 3-sigma extent projects to ``footprint_px`` pixels (uniform in [1, 3] by
default) and opacities in [0.3, 0.9]. It falls back to a synthetic slanted wall when the bundled data
is absent. Times are medians (and minima, and process CPU time) over ``repeats`` after one warm-up,
per available backend; the torch thread count is the caller's (the CLI leaves torch's default).
"""

from __future__ import annotations

import logging
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from gsslam.mapping.rasterize import render

_log = logging.getLogger(__name__)

BUNDLED_TUM = Path(__file__).resolve().parents[2] / "data" / "rgbd_dataset_freiburg3_teddy_60"


def _frame(width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """(image [H, W, 3], depth [H, W] with NaN holes, K [3, 3], source name) at the bench size."""
    import cv2

    if BUNDLED_TUM.is_dir():
        from gsslam.datasets.tum import TumRgbdDataset

        ds = TumRgbdDataset(BUNDLED_TUM)
        fr = ds[0]
        intr = ds.intrinsics
        sx, sy = width / intr.width, height / intr.height
        image = cv2.resize(fr.image, (width, height), interpolation=cv2.INTER_AREA)
        depth = cv2.resize(fr.depth, (width, height), interpolation=cv2.INTER_NEAREST)
        K = np.array(
            [
                [intr.fx * sx, 0, (intr.cx + 0.5) * sx - 0.5],
                [0, intr.fy * sy, (intr.cy + 0.5) * sy - 0.5],
                [0, 0, 1],
            ]
        )
        return image, depth, K, "tum fr3/teddy frame 0"
    f = 0.9 * width
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    u = np.arange(width)[None, :].repeat(height, 0)
    depth = (2.0 + 1.5 * u / width).astype(np.float32)
    image = np.stack([u / width, np.linspace(0, 1, height)[:, None].repeat(width, 1), 0.5 + 0 * depth], -1)
    return image.astype(np.float32), depth, K, "synthetic slanted wall"


def make_scene(
    gaussians: int, width: int, height: int, footprint_px: tuple[float, float] = (1.0, 3.0), seed: int = 0
) -> dict:
    """Gaussian parameters (camera = world frame) seeded from a real depth map.

    Each axis scale is drawn so that its 3-sigma extent projects to ``footprint_px`` pixels
    (uniform); the 0.3 px^2 low-pass filter then widens small Gaussians a little.
    """
    image, depth, K, source = _frame(width, height)
    rng = np.random.default_rng(seed)
    valid = np.argwhere(np.isfinite(depth) & (depth > 0.1))  # [M, 2] (v, u)
    pick = valid[rng.integers(0, len(valid), gaussians)]
    v = pick[:, 0] + rng.uniform(-0.5, 0.5, gaussians)
    u = pick[:, 1] + rng.uniform(-0.5, 0.5, gaussians)
    z = depth[pick[:, 0], pick[:, 1]].astype(np.float64)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    means = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], -1)
    scales = rng.uniform(*footprint_px, size=(gaussians, 3)) / 3.0 * (z / fx)[:, None]
    quats = rng.normal(size=(gaussians, 4))
    f32 = dict(dtype=torch.float32)
    return {
        "means": torch.tensor(means, **f32),
        "quats": torch.tensor(quats, **f32),
        "scales": torch.tensor(scales, **f32),
        "opacities": torch.tensor(rng.uniform(0.3, 0.9, gaussians), **f32),
        "colors": torch.tensor(image[pick[:, 0], pick[:, 1]], **f32),
        "T_cam_world": torch.eye(4, **f32),
        "K": torch.tensor(K, **f32),
        "source": source,
    }


def _time(fn, repeats: int) -> tuple[float, float, float]:
    """(median wall, min wall, median process CPU) milliseconds over ``repeats`` calls after a warm-up.

    The CPU time (summed over threads) is the work done; on a shared, oversubscribed machine it is a
    far steadier number than wall time.
    """
    fn()  # warm-up (and kernel build on first use)
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    ms = lambda v: round(1000.0 * v, 2)  # noqa: E731
    return ms(statistics.median(wall)), ms(min(wall)), ms(statistics.median(cpu))


def _backends() -> list[tuple[str, str]]:
    from gsslam.mapping import rasterize_cpu

    out = [("torch", "cpu")]
    if rasterize_cpu.available(torch.zeros(1)):
        out.append(("c", "cpu"))
    if torch.cuda.is_available():
        out.append(("torch", "cuda"))
        try:
            import gsplat  # noqa: F401

            out.append(("gsplat", "cuda"))
        except ImportError:
            pass
    return out


def run(
    gaussians: int = 20000,
    width: int = 160,
    height: int = 120,
    repeats: int = 10,
    footprint_px: tuple[float, float] = (1.0, 3.0),
) -> dict:
    """Median (and min) fw and fw+bw milliseconds per backend on a realistic scene; a JSON-able dict.

    fw+bw is one render plus the backward of a loss touching colour, depth, normal and alpha, with
    gradients for every Gaussian parameter and the pose. The pure-torch reference is timed with at
    most 3 repeats (it takes seconds).
    """
    scene = make_scene(gaussians, width, height, footprint_px)
    result: dict = {
        "gaussians": gaussians,
        "size": f"{width}x{height}",
        "scene": scene.pop("source"),
        "footprint_px": list(footprint_px),
        "torch_threads": torch.get_num_threads(),
        "repeats": repeats,
        "backends": {},
    }
    for backend, device in _backends():
        params = {k: t.to(device) for k, t in scene.items()}
        grads = [
            params[k].requires_grad_(True)
            for k in ("means", "quats", "scales", "opacities", "colors", "T_cam_world")
        ]
        sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)

        def forward(params=params, backend=backend):
            return render(**params, width=width, height=height, background=None, backend=backend)

        def fw(forward=forward, sync=sync):
            with torch.no_grad():
                forward()
            sync()

        def fwbw(forward=forward, sync=sync, grads=grads):
            out = forward()
            loss = out.color.sum() + out.depth.sum() + out.normal.sum() + out.alpha.sum()
            loss.backward()
            for g in grads:
                g.grad = None
            sync()

        reps = repeats if backend != "torch" or device == "cuda" else max(1, min(repeats, 3))
        with torch.no_grad():
            out = forward()
        fw_med, fw_min, fw_cpu = _time(fw, reps)
        fwbw_med, fwbw_min, fwbw_cpu = _time(fwbw, reps)
        entry = {
            "fw_ms": fw_med,
            "fwbw_ms": fwbw_med,
            "fw_min_ms": fw_min,
            "fwbw_min_ms": fwbw_min,
            "fw_cpu_ms": fw_cpu,
            "fwbw_cpu_ms": fwbw_cpu,
            "visible": int((out.radii > 0).sum()),
            "mean_radius_px": round(float(out.radii[out.radii > 0].float().mean()), 2),
            "coverage": round(float((out.alpha > 0.5).float().mean()), 3),
        }
        result["backends"][f"{backend}-{device}"] = entry
        _log.info("%s-%s: fw %.1f ms, fw+bw %.1f ms", backend, device, entry["fw_ms"], entry["fwbw_ms"])
    return result
