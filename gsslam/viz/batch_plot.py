"""The batch plot: ATE per sequence, one bar per configuration (matplotlib Agg, imported lazily)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gsslam.viz.plots import PlotError


def plot_ate_bars(path: str | Path, rows: list[dict], title: str = "") -> Path:
    """Write a PNG of ``ate_m`` (cm) per sequence (groups) and configuration (bars); missing = no bar."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise PlotError("plots need matplotlib: pip install 'gsslam[viz]'") from None
    seqs = list(dict.fromkeys(r["sequence"] for r in rows))
    configs = list(dict.fromkeys(r["config"] for r in rows))
    if not seqs:
        raise PlotError("no runs to plot")
    ate = np.full((len(seqs), len(configs)), np.nan)
    for r in rows:
        if r.get("status") == "ok" and r.get("ate_m") is not None:
            ate[seqs.index(r["sequence"]), configs.index(r["config"])] = 100.0 * r["ate_m"]
    fig = Figure(figsize=(max(6.0, 0.9 * len(seqs) * max(1, len(configs)) ** 0.5 + 2), 4.5), dpi=100,
                 layout="constrained")  # fmt: skip
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    width = 0.8 / len(configs)
    x = np.arange(len(seqs))
    for k, c in enumerate(configs):
        ax.bar(x - 0.4 + (k + 0.5) * width, np.nan_to_num(ate[:, k]), width, label=c)
        for xi in x[np.isnan(ate[:, k])]:  # a run without ATE: marked, not drawn as zero
            ax.text(xi - 0.4 + (k + 0.5) * width, 0, "×", ha="center", va="bottom", color="tab:red")
    ax.set_xticks(x, seqs, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("ATE RMSE [cm]")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title or "ATE per sequence", fontsize=11)
    out = Path(path)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, format="png")
    except OSError as e:
        raise PlotError(f"cannot write plot {out}: {e}") from None
    return out
