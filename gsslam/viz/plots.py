"""Static trajectory plots (matplotlib, Agg canvas: no window, no global pyplot state).

matplotlib is imported inside the functions, so importing this module is cheap.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gsslam.errors import GsslamError
from gsslam.io.atomic import atomic_path


class PlotError(GsslamError):
    """A plot cannot be made (matplotlib missing, nothing to draw, unwritable path)."""


def _top_view_axes(xyz: np.ndarray) -> tuple[int, int]:  # xyz [N, 3]
    """The two coordinate axes along which ``xyz`` spreads the most (in axis order)."""
    a, b = sorted(np.argsort(np.ptp(xyz, axis=0))[-2:])
    return int(a), int(b)


def plot_trajectory(
    path: str | Path,
    timestamps: np.ndarray,  # [M] seconds
    gt_xyz: np.ndarray,  # [M, 3] ground-truth positions
    est_xyz: np.ndarray,  # [M, 3] aligned estimated positions (paired with gt_xyz)
    title: str = "",
) -> Path:
    """Write a PNG: the aligned estimate over ground truth from the top, and x, y, z against time."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise PlotError("plots need matplotlib: pip install 'gsslam[viz]'") from None
    gt_xyz, est_xyz = np.asarray(gt_xyz), np.asarray(est_xyz)
    if len(gt_xyz) == 0 or gt_xyz.shape != est_xyz.shape:
        raise PlotError(f"need paired [M, 3] positions to plot, got {gt_xyz.shape} and {est_xyz.shape}")
    t = np.asarray(timestamps, dtype=np.float64) - float(np.min(timestamps))
    names = "xyz"
    a, b = _top_view_axes(gt_xyz)

    fig = Figure(figsize=(12, 6), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(3, 2, width_ratios=(1.1, 1))
    top = fig.add_subplot(grid[:, 0])
    top.plot(gt_xyz[:, a], gt_xyz[:, b], "-", color="0.35", lw=2, label="ground truth")
    top.plot(est_xyz[:, a], est_xyz[:, b], "-", color="tab:blue", lw=1.2, label="estimate (aligned)")
    top.plot(*gt_xyz[0, [a, b]], "o", color="0.35", ms=6, label="start")
    top.set_xlabel(f"{names[a]} [m]")
    top.set_ylabel(f"{names[b]} [m]")
    top.set_aspect("equal", adjustable="datalim")
    top.grid(True, alpha=0.3)
    top.legend(loc="best", fontsize=9)
    top.set_title(f"top view ({names[a]}-{names[b]} plane)", fontsize=10)
    for k in range(3):
        ax = fig.add_subplot(grid[k, 1])
        ax.plot(t, gt_xyz[:, k], "-", color="0.35", lw=2)
        ax.plot(t, est_xyz[:, k], "-", color="tab:blue", lw=1.2)
        ax.set_ylabel(f"{names[k]} [m]")
        ax.grid(True, alpha=0.3)
        if k == 2:
            ax.set_xlabel("time [s]")
        else:
            ax.tick_params(labelbottom=False)
    if title:
        fig.suptitle(title, fontsize=11)
    out = Path(path)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(out) as tmp:
            fig.savefig(tmp, format="png")
    except OSError as e:
        raise PlotError(f"cannot write plot {out}: {e}") from None
    return out


def plot_rss(path: str | Path, series: dict[str, list[tuple[int, float]]], title: str = "") -> Path:
    """Resident memory (MB) against frame index, one line per run: ``series[label] = [(frame, MB)]``."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise PlotError("plots need matplotlib: pip install 'gsslam[viz]'") from None
    fig = Figure(figsize=(6, 3.5), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    for label, pts in series.items():
        if pts:
            f, mb = zip(*pts)
            ax.plot(f, mb, label=label)
    ax.set_xlabel("frame")
    ax.set_ylabel("resident memory (MB)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.savefig(str(path))
    return Path(path)
