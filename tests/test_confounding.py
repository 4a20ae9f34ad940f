"""Two variables flown together: a cause in one of them is confounded with the other, and the plan flies
what separates them."""

from __future__ import annotations

import json
from pathlib import Path

from campaign.cli import main
from campaign.simulation.aircraft import DEFAULT_AIRCRAFT
from campaign.validation.support import matrix_toml
from diagnose.config import DEFAULTS

ROOT = Path(__file__).resolve().parents[1]

#: Four conditions, each flown as a level deceleration only: the throttle eased back by 0.3 under the
#: altitude hold, 30 s; alpha rises 2 to 3 deg as Mach falls 0.03 to 0.04.
DECELERATIONS = matrix_toml(
    [("up", 5, [0.28, 0.32, 0.36, 0.40], 5000)],
    "decel",
    '[defaults]\nmaneuvers_gear_up = ["deceleration"]\n[maneuvers.deceleration]\nthrottle_cut = 0.3\n'
    "duration_s = 30.0\n[stall.clmax_by_flap]\n5 = 1.90\n",
)
#: What the plan may fly next: a 2-3-1-1 (alpha moves, Mach does not) or another deceleration.
CANDIDATES = matrix_toml(
    [("up", 5, [0.28, 0.40], 5000)],
    "next",
    '[defaults]\nmaneuvers_gear_up = ["doublet", "deceleration"]\n[maneuvers.doublet]\ntail_s = 2.0\n'
    "stabilizer_amplitude_deg = 0.0\n[stall.clmax_by_flap]\n5 = 1.90\n",
)


def test_a_lift_in_alpha_flown_in_decelerations_is_confounded_and_the_plan_flies_doublets(tmp_path):
    """A lift effect linear in alpha hidden in decelerations (alpha and Mach correlate at -0.98 over the
    fitted logs): the diagnosis names a lift discrepancy, says that alpha and Mach are flown together, marks
    the cause confounded with its reading in the other variable as a rival the data do not settle; the plan
    separates them with 2-3-1-1s, which move alpha at one Mach."""
    (tmp_path / "m.toml").write_text(DECELERATIONS)
    (tmp_path / "next.toml").write_text(CANDIDATES)
    effect = ROOT / "tests" / "data" / "lift_alpha_linear.xml"
    assert (
        main(
            [
                "run",
                "--matrix",
                str(tmp_path / "m.toml"),
                "--effects",
                str(effect),
                "--noise",
                "flight-test",
                "--seed",
                "3",
                "--out",
                str(tmp_path / "data"),
                "--no-identify",
                "--no-replay",
                "--quiet",
                "--jobs",
                "2",
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "diagnose",
                "--data",
                str(tmp_path / "data"),
                "--model",
                str(DEFAULT_AIRCRAFT),
                "--out",
                str(tmp_path / "d"),
                "--no-plots",
                "--quiet",
                "--jobs",
                "2",
            ]
        )
        == 0
    )
    doc = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    pair = next(p for p in doc["moved_together"] if set(p["variables"]) == {"alpha_deg", "mach"})
    assert pair["corr"] < -0.9
    lift = next(c for c in doc["causes"] if c["kind"] == "aero" and c["coefficient"] == "CL")
    assert set(lift["variables"]) & {"alpha_deg", "mach"}, lift["variables"]
    note = lift["evidence"]["confounded"]
    other = ({"alpha_deg", "mach"} - set(lift["variables"])).pop()
    assert any(other in r["rival"] and not r["settled"] for r in note["rivals"]), note
    text = (tmp_path / "d" / "diagnosis.txt").read_text()
    assert (
        "flown together, across the fitted logs and within them" in text and "confounded: the fitted logs fly" in text
    )
    assert (
        main(
            [
                "plan",
                "--diagnosis",
                str(tmp_path / "d"),
                "--matrix",
                str(tmp_path / "next.toml"),
                "--out",
                str(tmp_path / "plan"),
                "--jobs",
                "2",
                "--quiet",
            ]
        )
        == 0
    )
    plan = json.loads((tmp_path / "plan" / "plan.json").read_text())
    assert any(f["maneuver"] == "doublet" for f in plan["flights"]), plan["flights"]
    mine = [
        r
        for r in plan["rivals"]
        if r["cause"] == f"{lift['coefficient']} vs {', '.join(lift['variables'])}" and other in r["rival"]
    ]
    assert mine and all(r["planned_se"] > max(r["now_se"], DEFAULTS.settled_se) for r in mine), mine


def _deceleration_frame(seed: int = 0):
    """Residual data of three logs, each a deceleration: Mach falls as alpha rises (correlation about -0.95)."""
    import numpy as np
    import pandas as pd

    rng = np.random.default_rng(seed)
    frames = []
    for i in range(3):
        t = np.linspace(0.0, 1.0, 400)
        mach = 0.30 - 0.06 * t + 0.003 * rng.standard_normal(t.size)
        alpha = 4.0 + 8.0 * t + 0.4 * rng.standard_normal(t.size)
        frames.append(pd.DataFrame({"log": f"l{i}", "alpha_deg": alpha, "mach": mach, "r_Cm": 0.0 * t}))
    return pd.concat(frames, ignore_index=True)


def test_a_curve_in_one_of_two_variables_flown_together_has_the_curve_in_the_other_as_its_reading():
    """Over a deceleration a curve in Mach scaled by alpha reads as a curve in alpha scaled by Mach: that is
    its rival, marked as the reading in the partner; the data preferring it however much never swap it in
    (where the two extrapolate they differ most), while an ordinary rival preferred as much is taken."""
    from diagnose.causes import Cause
    from diagnose.separation import preferred_aero_rivals
    from diagnose.terms import candidate_terms
    from diagnose.together import confounded_note, flown_together, in_partner

    data = _deceleration_frame()
    pairs = flown_together(data)
    assert [set(p["variables"]) for p in pairs] == [{"alpha_deg", "mach"}]
    pool = candidate_terms(data, "Cm")
    by = {t.label: t for t in pool}
    curve = by["smooth(mach) x alpha_deg"]
    assert by["smooth(alpha_deg) x mach"] in in_partner(curve, pool, pairs)

    def cause(rival: str) -> Cause:
        doc = {"kind": "aero", "term": rival, "replaces": curve.label, "separation_se": -20.0}
        return Cause(
            "Cm",
            ["mach", "alpha_deg"],
            [curve],
            "linear",
            {"rivals": [{**doc, "rival": f"Cm: {rival}"}]},
            0.01,
            verdict={"accepted": True},
        )

    reading = cause("smooth(alpha_deg) x mach")
    note = confounded_note(reading, pairs, DEFAULTS.settled_se)
    assert [r["rival"] for r in note["rivals"]] == ["Cm: smooth(alpha_deg) x mach"] and not note["settled"]
    assert preferred_aero_rivals([reading], {"Cm": pool}, data) == {}
    other = cause("smooth(alpha_deg)")
    assert preferred_aero_rivals([other], {"Cm": pool}, data) == {"Cm": {curve: by["smooth(alpha_deg)"]}}
