"""The diagnosis's decision thresholds live in one documented object, and the decisions read them there."""

from __future__ import annotations

import dataclasses
import json
import pickle
from pathlib import Path

import pytest

from diagnose.config import DEFAULTS, DiagnosisSettings, current, recorded, using
from identify.compat import CompatResult, CompatSettings, Parameter
from infra.settings import markdown_table, rows, undocumented

ROOT = Path(__file__).resolve().parents[1]


def test_every_setting_is_documented_once_with_its_unit_and_what_it_guards():
    assert not undocumented(DiagnosisSettings), undocumented(DiagnosisSettings)
    names = [r["name"] for r in rows(DiagnosisSettings)]
    fields = [f.name for f in dataclasses.fields(DiagnosisSettings) if f.name != "compat"]
    assert names == fields + [f"compat.{f.name}" for f in dataclasses.fields(CompatSettings)]
    table = markdown_table(DiagnosisSettings)
    assert all(f"| `{n}` |" in table for n in names) and len(table.splitlines()) == len(names) + 2
    for cls in (DiagnosisSettings, CompatSettings):  # help() shows them too
        assert all(f"\n{f.name} : " in cls.__doc__ for f in dataclasses.fields(cls)), cls
    text = " ".join(r["guards"] + r["calibration"] for r in rows(DiagnosisSettings))
    for history in ("stop ", "seed", "fresh", "development"):
        assert history not in text.lower(), history


def test_the_settings_go_to_json_and_back_and_the_report_reads_them_there():
    s = DiagnosisSettings(replicate_gain=1.7, tail_levels=(0.01, 0.99), compat=CompatSettings(apply_z=6.0))
    doc = json.loads(json.dumps({"settings": s.to_dict()}))
    assert recorded(doc) == s and recorded({}) == DEFAULTS
    assert DiagnosisSettings.from_dict({"settled_se": 4.0, "unknown": 1}).settled_se == 4.0


def test_the_settings_are_current_within_their_block_only():
    s = DiagnosisSettings(settled_se=3.0)
    assert current() is DEFAULTS
    with using(s):
        assert current() is s
        with using(None):
            assert current() is DEFAULTS
        assert current() is s
    assert current() is DEFAULTS
    with pytest.raises(TypeError, match="DiagnosisSettings"), using({"settled_se": 3.0}):
        pass


def test_a_compat_parameter_decides_by_the_settings_it_carries_into_a_worker():
    """What corrects the logs in a worker process is the data compatibility's result, pickled: each of
    its parameters keeps the thresholds it was estimated with."""

    def vane(settings):
        return CompatResult([Parameter("alpha_deg", "bias", "deg", 0.3, 0.05, settings=settings)])

    assert vane(CompatSettings()).applied  # 6 standard errors: applied at 5
    strict = pickle.loads(pickle.dumps(vane(CompatSettings(apply_z=8.0))))
    assert strict.get("alpha_deg.bias").settings.apply_z == 8.0
    assert not strict.applied and strict.undecided  # a candidate only: other evidence must choose it


@pytest.fixture(scope="module")
def narrow(tmp_path_factory):
    """The README's own campaign: a gear x alpha pitching moment hidden in our 737, flown through the
    flight-test instruments."""
    from campaign.cli import main

    out = tmp_path_factory.mktemp("settings") / "narrow"
    assert (
        main(
            [
                "run",
                "--matrix",
                str(ROOT / "docs/examples/narrow.toml"),
                "--effects",
                str(ROOT / "docs/examples/gear-alpha-moment.xml"),
                "--noise",
                "flight-test",
                "--seed",
                "6",
                "--out",
                str(out),
                "--no-identify",
                "--no-replay",
                "--jobs",
                "2",
                "--quiet",
            ]
        )
        == 0
    )
    return out


def test_a_threshold_changed_in_the_settings_changes_the_decision(narrow, tmp_path):
    """With the defaults the hidden moment is named as it always was (the same F, size and held-out gain);
    asked for a held-out gain of x100, the same data leave it a discrepancy whose cause is not confirmed,
    and the reason quotes the threshold asked for. gearaero.diagnose hands the settings through to the
    decision and diagnosis.json records them."""
    import gearaero as ga
    from campaign.diagnosis.run import load_data, split
    from diagnose.diagnosis import diagnose
    from diagnose.evaluate import ModelEvaluator

    logs = load_data(narrow)
    train, held = split(logs, first=logs, source=str(narrow))
    evaluator = ModelEvaluator(ga.SHIPPED_737)
    try:
        diag = diagnose(train, evaluator, held, jobs=2)
    finally:
        evaluator.close()
    assert [c.label for c in diag.causes] == ["Cm vs gear_norm, alpha_deg"] and diag.settings == DEFAULTS
    v, e = diag.causes[0].verdict, diag.causes[0].evidence
    assert e["F"] == pytest.approx(3337.128, rel=1e-5) and v["size_over_floor"] == pytest.approx(15.128, rel=1e-4)
    assert v["replicate_gain"] == pytest.approx(12.265, rel=1e-4)

    strict = DiagnosisSettings(replicate_gain=100.0, departs_gain=100.0)
    result = ga.diagnose(narrow, ga.SHIPPED_737, tmp_path / "strict", settings=strict, plots="none", jobs=2)
    assert result.verdict == "discrepancy, cause not confirmed" and not result.causes
    first = result.to_dict()["unconfirmed"][0]
    assert "needs x100.0" in first["verdict"]["reason"] and first["verdict"]["replicate_gain"] == v["replicate_gain"]
    assert recorded(json.loads((tmp_path / "strict" / "diagnosis.json").read_text())) == strict == result.settings
    with pytest.raises(TypeError, match="DiagnosisSettings"):
        ga.diagnose(narrow, ga.SHIPPED_737, tmp_path / "wrong", settings={"replicate_gain": 100.0})
    assert not (tmp_path / "wrong").exists()
