"""The batch table maths: means per configuration, Markdown / CSV text, comparison of two batches."""

from __future__ import annotations

import csv
import io

import pytest

from gsslam.run.results import DASH, compare_markdown, compare_rows, csv_text, markdown, means_by_config


def _row(seq, config, ate=None, status="ok", **kw):
    return {"sequence": seq, "config": config, "status": status, "ate_m": ate, "mode": "rgbd", **kw}


ROWS = [
    _row(
        "a", "base", 0.010, fps=2.0, loops_enabled=True, loops_detected=3, loops_accepted=2, loops_rejected=1
    ),
    _row("a", "fast", 0.020, fps=4.0),
    _row("b", "base", 0.030, fps=1.0),
    _row("b", "fast", None, status="failed", error="RuntimeError: boom", fps=9.0),
    _row("c", "base", None, status="skipped", error="data not found: c"),
]


def test_means_use_finished_runs_with_the_value():
    means = {m["config"]: m for m in means_by_config(ROWS)}
    assert means["base"]["runs"] == 3 and means["base"]["ok"] == 2
    assert means["base"]["ate_m"] == pytest.approx(0.020) and means["base"]["n_ate_m"] == 2
    assert means["fast"]["ate_m"] == pytest.approx(0.020) and means["fast"]["fps"] == pytest.approx(4.0)
    assert means["fast"]["psnr"] is None and means["fast"]["n_psnr"] == 0


def test_markdown_lists_every_run_and_why_some_did_not_finish():
    md = markdown(ROWS, title="t")
    lines = md.splitlines()
    assert lines[0] == "# t"
    table = [ln for ln in lines if ln.startswith("| a ") or ln.startswith("| b ") or ln.startswith("| c ")]
    assert len(table) == 5
    assert "| 1.00 |" in table[0] and "3/2/1" in table[0]  # ATE in cm, loops d/a/r
    assert "off" in table[1] and DASH in table[3]
    assert "`b` / `fast`: failed: RuntimeError: boom" in md and "`c` / `base`: skipped: data not found" in md
    assert "| base | 2 / 3 | 2.00 |" in md


def test_csv_round_trips_numbers_and_lists():
    text = csv_text([{**ROWS[0], "overrides": ["x.y=1"]}, ROWS[3]])
    rows = list(csv.DictReader(io.StringIO(text)))
    assert float(rows[0]["ate_m"]) == 0.010 and rows[0]["overrides"] == '["x.y=1"]'
    assert rows[1]["ate_m"] == "" and rows[1]["error"] == "RuntimeError: boom"


def test_compare_gives_b_minus_a_per_sequence():
    b = [_row("a", "base", 0.008), _row("b", "base", 0.035), _row("d", "base", 0.1)]
    diff = {(r["sequence"], r["config"]): r for r in compare_rows(ROWS, b)}
    assert diff[("a", "base")]["ate_m_diff"] == pytest.approx(-0.002)
    assert diff[("b", "base")]["ate_m_diff"] == pytest.approx(0.005)
    assert diff[("b", "fast")]["fps_a"] is None  # a failed run's numbers are not compared
    assert diff[("d", "base")]["ate_m_a"] is None and diff[("d", "base")]["ate_m_diff"] is None
    md = compare_markdown(list(diff.values()))
    assert "| a | base | 1.00 | 0.80 | -0.20 |" in md and "| b | base | 3.00 | 3.50 | +0.50 |" in md
