"""The speed results: one file per run, the comparison that names what got slower, and the speed page
made from the files (``benchmarks/compare.py``, ``benchmarks/tables.py``)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _result(commit: str, date: str, diagnose_s: float, cpu_s: float, stage_s: float) -> dict:
    return {
        "benchmark": "speed_table",
        "command": "python benchmarks/speed_table.py --diagnosis-only",
        "code_commit": commit,
        "code_date": date,
        "date": date,
        "machine": {"cpu": "x", "cores": 2},
        "figures": {
            "diagnose, no plots": {"wall_s": diagnose_s, "cpu_s": cpu_s, "sum_mb": 900.0, "others_busy": 0.1},
            "diagnose, key plots": {"wall_s": 20.0, "cpu_s": 30.0, "sum_mb": 950.0},
            "flying loop / raw fdm.run()": {"ratio": 0.8},
        },
        "stages": {"jobs": 2, "stages": {"verdict": {"wall_s": stage_s, "cpu_s": stage_s}}},
    }


def test_the_comparison_names_what_got_slower_by_more_than_the_threshold(tmp_path, capsys):
    compare = _load("compare")
    old = _result("a" * 40, "2026-01-01T10:00:00+00:00", 15.0, 30.0, 1.0)
    new = _result("b" * 40, "2026-01-02T10:00:00+00:00", 16.5, 37.5, 3.0)  # +10 % wall, +25 % CPU, stage x3
    for name, doc in (("old.json", old), ("new.json", new)):
        (tmp_path / name).write_text(json.dumps(doc))
    assert [f.name for f in compare.newest(2, tmp_path)] == ["old.json", "new.json"]
    rows = compare.changes(old, new, 20.0)
    slower = {(r["figure"], r["metric"]) for r in rows if r["slower"]}
    assert slower == {
        ("diagnose, no plots", "CPU"),
        ("diagnosis stage: verdict", "wall time"),
        ("diagnosis stage: verdict", "CPU"),
    }
    assert compare.main([str(tmp_path / "old.json"), str(tmp_path / "new.json")]) == 1
    assert "SLOWER diagnose, no plots, CPU: 30 -> 37.5 s (+25 %)" in capsys.readouterr().out
    assert compare.main([str(tmp_path / "old.json"), str(tmp_path / "old.json")]) == 0


def test_the_speed_page_shows_the_last_two_diagnoses_side_by_side(tmp_path, monkeypatch):
    tables = _load("tables")
    monkeypatch.setattr(tables, "SPEED", tmp_path)
    (tmp_path / "a.json").write_text(json.dumps(_result("a" * 40, "2026-01-01T10:00:00+00:00", 33.0, 60.0, 8.0)))
    (tmp_path / "b.json").write_text(json.dumps(_result("b" * 40, "2026-01-02T10:00:00+00:00", 14.0, 28.0, 1.0)))
    page = tables.speed_page()
    assert "| diagnose, no plots | 33.0 | 60.0 | 900 | - | 14.0 | 28.0 | 900 | - |" in page
    assert "`aaaaaaa` wall [s]" in page and "`bbbbbbb` wall [s]" in page
    assert "| verdict | 8.00 | 8.00 | 1.00 | 1.00 |" in page
