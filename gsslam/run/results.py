"""The batch table: rows of run results, means per configuration, comparison of two batches (pure).

A row is a flat dict: the run's identity (``sequence``, ``config``, ``dataset``, ``status``, ``error``) and
the numbers of :func:`gsslam.run.run_metrics.evaluate_run` (``None`` when not measured). Nothing here reads
or writes files: the functions return rows and text (Markdown, CSV) for the batch to write.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

DASH = "—"


@dataclass(frozen=True)
class Column:
    key: str
    header: str
    fmt: Callable[[Any], str]
    numeric: bool = True


def _f(spec: str, scale: float = 1.0) -> Callable[[Any], str]:
    def fmt(v: Any) -> str:
        if v is None or (isinstance(v, float) and math.isnan(v)):
            return DASH
        return format(scale * v, spec)

    return fmt


def _s(v: Any) -> str:
    return DASH if v is None else str(v)


def _loops(row: dict) -> str:
    if not row.get("loops_enabled"):
        return "off" if row.get("status") == "ok" else DASH
    return f"{row.get('loops_detected')}/{row.get('loops_accepted')}/{row.get('loops_rejected')}"


COLUMNS: tuple[Column, ...] = (
    Column("sequence", "sequence", _s, numeric=False),
    Column("config", "config", _s, numeric=False),
    Column("mode", "mode", _s, numeric=False),
    Column("status", "status", _s, numeric=False),
    Column("frames", "frames", _s),
    Column("ate_m", "ATE cm", _f(".2f", 100)),
    Column("ate_kf_m", "ATE kf cm", _f(".2f", 100)),
    Column("ate_online_m", "ATE online cm", _f(".2f", 100)),
    Column("sim3_scale", "Sim3 scale", _f(".3f")),
    Column("rpe_t_m", "RPE cm", _f(".2f", 100)),
    Column("rpe_r_deg", "RPE deg", _f(".3f")),
    Column("t_rel_pct", "t_rel %", _f(".2f")),
    Column("r_rel_deg_per_100m", "r_rel deg/100m", _f(".3f")),
    Column("loops", "loops d/a/r", _s, numeric=False),
    Column("psnr", "PSNR dB", _f(".2f")),
    Column("ssim", "SSIM", _f(".3f")),
    Column("map_mb", "map MB", _f(".2f")),
    Column("fps", "FPS", _f(".2f")),
    Column("peak_rss_mb", "RSS MB", _f(".0f")),
    Column("wall_s", "wall s", _f(".1f")),
    Column("cpu_s", "CPU s", _f(".1f")),
    Column("backend", "raster", _s, numeric=False),
)
MEAN_KEYS = tuple(c.key for c in COLUMNS if c.numeric and c.key != "frames")


def cell(row: dict, col: Column) -> str:
    if col.key == "loops":
        return _loops(row)
    return col.fmt(row.get(col.key))


def means_by_config(rows: list[dict]) -> list[dict]:
    """Per configuration (in first-seen order): ``runs``, ``ok`` and the mean of each numeric column over
    its finished runs that have the value (``n_<key>`` counts them; compare configurations on the same
    sequences only)."""
    out = []
    for config in dict.fromkeys(r["config"] for r in rows):
        mine = [r for r in rows if r["config"] == config]
        ok = [r for r in mine if r.get("status") == "ok"]
        mean: dict[str, Any] = {"config": config, "runs": len(mine), "ok": len(ok)}
        for key in MEAN_KEYS:
            vals = [float(r[key]) for r in ok if r.get(key) is not None]
            mean[key] = sum(vals) / len(vals) if vals else None
            mean[f"n_{key}"] = len(vals)
        out.append(mean)
    return out


def _md_table(headers: list[str], lines: list[list[str]]) -> str:
    text = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    text += ["| " + " | ".join(cells) + " |" for cells in lines]
    return "\n".join(text)


def markdown(rows: list[dict], title: str = "batch") -> str:
    """The per-run table, the means per configuration and the failed / skipped runs' reasons."""
    cols = list(COLUMNS)
    parts = [
        f"# {title}",
        "",
        _md_table([c.header for c in cols], [[cell(r, c) for c in cols] for r in rows]),
    ]
    mean_cols = [c for c in COLUMNS if c.key in MEAN_KEYS]
    means = means_by_config(rows)
    parts += [
        "",
        "## Means per configuration (finished runs)",
        "",
        _md_table(
            ["config", "ok / runs"] + [c.header for c in mean_cols],
            [[m["config"], f"{m['ok']} / {m['runs']}"] + [c.fmt(m[c.key]) for c in mean_cols] for m in means],
        ),
    ]
    notes = [r for r in rows if r.get("status") != "ok"]
    if notes:
        parts += ["", "## Runs not finished", ""]
        parts += [
            f"- `{r['sequence']}` / `{r['config']}`: {r['status']}: {r.get('error') or ''}" for r in notes
        ]
    return "\n".join(parts) + "\n"


def _csv_value(v: Any) -> Any:
    if v is None:
        return ""
    return json.dumps(v) if isinstance(v, dict | list | tuple) else v


def csv_text(rows: list[dict]) -> str:
    """Every key of every row (raw numbers, SI units), one line per run."""
    keys = list(dict.fromkeys(k for r in rows for k in r))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=keys, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: _csv_value(r.get(k)) for k in keys})
    return buf.getvalue()


COMPARE_KEYS = ("ate_m", "psnr", "fps")


def compare_rows(a: list[dict], b: list[dict], keys: tuple[str, ...] = COMPARE_KEYS) -> list[dict]:
    """Per (sequence, config) present in either batch: A's and B's value of each key and ``B - A``."""
    index_a = {(r["sequence"], r["config"]): r for r in a}
    index_b = {(r["sequence"], r["config"]): r for r in b}
    out = []
    for key in dict.fromkeys(list(index_a) + list(index_b)):
        ra, rb = index_a.get(key, {}), index_b.get(key, {})
        row: dict[str, Any] = {"sequence": key[0], "config": key[1]}
        for k in keys:
            va = ra.get(k) if ra.get("status") == "ok" else None
            vb = rb.get(k) if rb.get("status") == "ok" else None
            row[f"{k}_a"], row[f"{k}_b"] = va, vb
            row[f"{k}_diff"] = None if va is None or vb is None else vb - va
        out.append(row)
    return out


def compare_markdown(diff: list[dict], keys: tuple[str, ...] = COMPARE_KEYS) -> str:
    cols = {c.key: c for c in COLUMNS}
    headers = ["sequence", "config"]
    for k in keys:
        h = cols[k].header
        headers += [f"{h} A", f"{h} B", f"Δ {h}"]
    lines = []
    for r in diff:
        cells = [r["sequence"], r["config"]]
        for k in keys:
            fmt = cols[k].fmt
            d = r[f"{k}_diff"]
            cells += [
                fmt(r[f"{k}_a"]),
                fmt(r[f"{k}_b"]),
                DASH if d is None else ("+" if d >= 0 else "") + fmt(d),
            ]
        lines.append(cells)
    return _md_table(headers, lines) + "\n"
