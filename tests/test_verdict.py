"""The verdict on effects the diagnosis was not built against (tests/shapes.py): what it named first,
and never "no significant discrepancy" to an effect that dominates the residual.

Only these tests read the overlays, to score the answer."""

from pathlib import Path

import numpy as np
import pytest

from campaign.simulation.aircraft import DEFAULT_AIRCRAFT
from campaign.validation.hidden import (
    DIAG_MATRIX,
    diagnose_overlay,
    discrepancies,
    score,
)
from campaign.validation.shapes import draw
from campaign.validation.support import matrix_toml


def _named_first(r: dict, effect) -> bool:
    """The largest aero discrepancy named, a cause or one the data cannot confirm, is the effect's
    coefficient and (first) variable."""
    return bool(r.get("coefficient_ok") and r["doc"]["discrepancy"]) and (
        discrepancies(r["doc"])[0]["variables"][0] == effect.variables[0]
    )


def test_an_effect_zero_gear_up_is_named_where_most_rows_are_gear_down(tmp_path):
    """A drag rise over the last part of the gear travel, and a condition flown gear up only: the effect
    is zero there, and so is its fitted contribution (the gear term's reference is gear up). It acts
    where it departs from the model, never where a log departs from the median row (most rows are
    gear down): the gear-up condition, left out, must not veto it."""
    matrix = DIAG_MATRIX + matrix_toml([("up", 0, 0.4, 5000)]).split("\n", 1)[1]
    effect = draw(np.random.default_rng(11), 50, 50, "CD", ("gear_norm",), "late_onset")
    r = score(tmp_path, effect, seed=11, matrix=matrix, shape=False)
    assert r["discrepancy"] and _named_first(r, effect), (effect.description, r["doc"]["summary"])
    first = r["doc"]["causes"][0]
    gear_up_logs = [i for i, p in enumerate(r["doc"]["data"]["train"] + r["doc"]["data"]["held_out"]) if "_gup__" in p]
    acting = set(first["verdict"]["holdout_logs"])
    assert acting and not acting & set(gear_up_logs), first["verdict"]["holdout_logs"]


#: Seeds of the random shapes: the benchmark reports on others (benchmarks/detection_curve.py).
#: None is a known miss: 904 (a 4-knot alpha table in Cm) passes since a condition whose removal leaves the
#: terms unestimable no longer vetoes a cause; 900 (a gear x flap effect only the matrix's single flap-30
#: condition sees) since a strong cause at one condition, 3 times its floor, is named unconfirmed.
SHAPE_SEEDS = list(range(900, 906))


@pytest.mark.parametrize("seed", SHAPE_SEEDS)
def test_a_random_shape_ten_times_its_floor_is_named_first(tmp_path, seed):
    effect = draw(np.random.default_rng(seed), 10, 30)
    r = score(tmp_path, effect, seed=seed, shape=False)
    assert r["discrepancy"] and _named_first(r, effect), (effect.description, r["doc"]["summary"])


def test_a_drag_onset_with_flap_is_not_put_down_to_an_implausible_sideslip_vane_bias(tmp_path):
    """Our 737 in 3 ft/s with CD 0.006 lower at flap 30, an onset above 20 deg (seed
    5,000,001 of the detection curve), beside a +0.047 ft/s^2 ax bias. The kinematics hardly measure the
    sideslip vane's bias in longitudinal manoeuvres (+- 10 deg); within 2 of those standard errors, a
    -19 deg bias, through the wind axes, made all of the drag change, and nothing was named. No
    instrument error is taken as larger than plausible (5 deg)."""
    doc = diagnose_overlay(
        tmp_path,
        "drag_flap_late_onset.xml",
        DEFAULT_AIRCRAFT,
        DIAG_MATRIX,
        5000001,
        sigma_fps=3.0,
        channels="[channels.ax_fps2]\nbias = 0.04684199312701896\n",
    )
    aero = discrepancies(doc)
    assert aero and aero[0]["coefficient"] == "CD" and aero[0]["variables"][0] == "flap_deg", doc["summary"]


MACH_STEP = """<effects>
  <axis name="LIFT">
    <function name="aero/coefficient/hidden-mach-step">
      <product>
        <property>aero/qbar-psf</property>
        <property>metrics/Sw-sqft</property>
        <table>
          <independentVar>velocities/mach</independentVar>
          <tableData>
            0.0 0.0
            0.38 0.0
            0.42 0.03
            1.0 0.03
          </tableData>
        </table>
      </product>
    </function>
  </axis>
</effects>
"""


@pytest.mark.slow
def test_a_lift_step_with_mach_is_named_on_the_paper_matrix(tmp_path):
    """CL a few hundredths higher above Mach 0.4, the paper's matrix through the flight-test profile:
    one condition left out (2000/0.3/15, x0.88) vetoed this effect, tens of times its floor with a
    pooled held-out gain of x8.8; a strong cause is no longer vetoed by one condition."""
    import json

    from campaign.cli import main
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT

    fx = tmp_path / "step.xml"
    fx.write_text(MACH_STEP)
    assert (
        main(
            [
                "run",
                "--effects",
                str(fx),
                "--noise",
                "flight-test",
                "--seed",
                "13",
                "--out",
                str(tmp_path / "d"),
                "--jobs",
                "2",
                "--no-identify",
                "--quiet",
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "diagnose",
                "--data",
                str(tmp_path / "d"),
                "--model",
                str(DEFAULT_AIRCRAFT),
                "--out",
                str(tmp_path / "r"),
                "--jobs",
                "2",
                "--no-plots",
                "--quiet",
            ]
        )
        == 0
    )
    doc = json.loads((tmp_path / "r" / "diagnosis.json").read_text())
    first = next(c for c in doc["causes"] if c["kind"] == "aero")
    assert (first["coefficient"], first["variables"][0]) == ("CL", "mach"), doc["summary"]
    assert first["verdict"]["holdout_gain"] >= 1.5 and first["verdict"]["size_over_floor"] >= 10


def test_a_condition_whose_removal_leaves_the_cause_unestimable_cannot_veto_it():
    """Cm 0.02 higher at flap 15, flown at one condition of three (the stock A320's matrix): left out,
    the two flap-0 conditions cannot estimate a term in flap, so that condition says nothing; the
    flap-0 conditions, each left out, are predicted by the rest, and the cause improves them."""
    import pandas as pd

    from diagnose.causes import Cause
    from diagnose.stepwise import StepwiseResult
    from diagnose.terms import Term
    from diagnose.verdict import holdout_gain

    rng = np.random.default_rng(0)
    conds = ["5000/0.3/0", "10000/0.5/0", "5000/0.3/15"]
    frames = []
    for i, c in enumerate(conds):
        flap = 15.0 if c.endswith("/15") else 0.0
        frames.append(
            pd.DataFrame(
                {"condition": c, "log": i, "flap_deg": flap, "r_Cm": 0.02 * (flap > 0) + rng.normal(0, 0.002, 400)}
            )
        )
    data = pd.concat(frames, ignore_index=True)
    term = Term("linear", ("flap_deg",), centers=(5.0,), ranges=((0.0, 15.0),))
    x = np.column_stack([np.ones(len(data)), term.design(data)])
    beta = np.linalg.lstsq(x, data.r_Cm.to_numpy(), rcond=None)[0]
    res = StepwiseResult("Cm", [term], beta, {}, [], 0.0, 0.0, len(data))
    cause = Cause("Cm", ["flap_deg"], [term], "linear", {"p_value": 0.0}, 0.01, size=0.02)
    gain, acting, by = holdout_gain(res, cause, data)
    assert sorted(acting) == [0, 1, 2]
    assert np.isnan(by["5000/0.3/15"]) and by["5000/0.3/0"] > 3 and by["10000/0.5/0"] > 3
    assert gain > 3


def _mach_step(f_stat: float) -> tuple:
    """CL 0.0135 lower from Mach 0.35 up, flown at Mach 0.3 (twice), 0.4 and 0.5, as a cause of F
    ``f_stat``: the cause, its fit and its data."""
    import pandas as pd

    from diagnose.causes import Cause
    from diagnose.stepwise import StepwiseResult
    from diagnose.terms import Term

    rng = np.random.default_rng(2)
    conds = [("5000/0.3/0", 0.3), ("5000/0.3/15", 0.3), ("10000/0.4/0", 0.4), ("10000/0.5/0", 0.5)]
    data = pd.concat(
        [
            pd.DataFrame(
                {
                    "condition": c,
                    "log": i,
                    "mach": m + rng.normal(0, 0.002, 400),
                    "r_CL": -0.0135 * (m > 0.35) + rng.normal(0, 0.0015, 400),
                }
            )
            for i, (c, m) in enumerate(conds)
        ],
        ignore_index=True,
    )
    term = Term("linear", ("mach",), centers=(0.3,), ranges=((0.3, 0.5),))
    x = np.column_stack([np.ones(len(data)), term.design(data)])
    beta = np.linalg.lstsq(x, data.r_CL.to_numpy(), rcond=None)[0]
    res = StepwiseResult("CL", [term], beta, {}, [], 0.0, 0.0, len(data))
    return Cause("CL", ["mach"], [term], "linear", {"p_value": 0.0, "F": f_stat}, 0.01, size=0.0135), res, data


def test_a_condition_outside_the_range_the_others_span_cannot_veto_a_cause():
    """CL 0.0135 lower from Mach 0.35 up, flown at Mach 0.3 (twice), 0.4 and 0.5 (the stock A320's
    four conditions): a line in Mach fitted without Mach 0.5 extrapolates the step to twice its
    size there, and that condition refuted a cause 15 times its floor (pooled x0.83). It lies
    outside what the others span and says nothing; Mach 0.4, between them, is predicted (half the
    step, against a third of it by the mean of the others) and gains x1.33. Only for a cause with F of
    1,000 or more: a weaker one is refuted by extrapolation as before."""
    from diagnose.verdict import holdout_gain

    cause, res, data = _mach_step(1e4)
    gain, _, by = holdout_gain(res, cause, data)
    assert np.isnan(by["10000/0.5/0"]) and by["10000/0.4/0"] > 1.25
    assert gain > 1.25
    weak, res, data = _mach_step(100.0)
    gain, _, by = holdout_gain(res, weak, data)  # below F 1000 extrapolation refutes, as it did
    assert by["10000/0.5/0"] < 1.0 and gain < 1.02


def test_extrapolation_cannot_refute_a_cause_ten_times_its_floor():
    """The Mach step of the test above with an F of 100: below 10 times its floor, the condition
    beyond the others' range still refutes it with the conditions left out in turn; from 10 times up
    (a CD bump in Mach at 15 times the floor on seed 3,600,091, x0.31 pooled for Mach
    0.5 predicted from the two below, x2.7 at the Mach 0.3 the others bracket), it can only confirm
    it. The decision, each log left out, counts rows within the others' range alone: here Mach 0.4,
    predicted half the step, names it either way."""
    from diagnose.config import DEFAULTS
    from diagnose.verdict import judge

    for floor, strong in ((0.0027, False), (0.00125, True)):
        cause, res, data = _mach_step(100.0)
        judge([cause], {"CL": res}, data, [np.array([floor])])
        v = cause.verdict
        assert v["accepted"] and v["replicate_gain"] >= DEFAULTS.replicate_gain, (floor, v["reason"])
        assert bool(np.isnan(v["holdout_gain_by_condition"]["10000/0.5/0"])) is strong


def test_a_strong_cause_at_one_condition_only_is_a_discrepancy_from_three_times_its_floor():
    """A lift step in Mach that only the one condition flown above it sees (seed
    3,600,045: CL +0.0127 from Mach 0.32, flown at 0.2, 0.3 and 0.5; F 6,500, 7.5 times its floor)
    is a discrepancy no other condition can confirm: named unconfirmed, not dismissed, when it is 3
    times its floor with an F of 1,000, or 10 times with an F of 60. A weak one (F 100 at 7.5 times, F 40
    at 18 times: what one condition's turbulence left as a level, null 8,700,158's F was 38) or a
    small one (twice the floor) is not."""
    import pandas as pd

    from diagnose.causes import Cause
    from diagnose.stepwise import StepwiseResult
    from diagnose.terms import Term
    from diagnose.verdict import judge

    rng = np.random.default_rng(4)
    conds = [("2000/0.2/30", 0.2), ("2000/0.3/0", 0.3), ("10000/0.3/0", 0.3), ("10000/0.5/0", 0.5)]
    data = pd.concat(
        [
            pd.DataFrame(
                {
                    "condition": c,
                    "log": i,
                    "mach": m + rng.normal(0, 0.001, 400),
                    "r_CL": 0.0127 * (m > 0.32) + rng.normal(0, 0.0015, 400),
                }
            )
            for i, (c, m) in enumerate(conds)
        ],
        ignore_index=True,
    )
    term = Term("smooth", ("mach",), (0.2, 0.3, 0.5))
    x = np.column_stack([np.ones(len(data)), term.design(data)])
    beta = np.linalg.lstsq(x, data.r_CL.to_numpy(), rcond=None)[0]
    res = StepwiseResult("CL", [term], beta, {}, [], 0.0, 0.0, len(data))
    for f_stat, floor, unconfirmed in (
        (6500.0, 0.0127 / 7.5, True),
        (100.0, 0.0127 / 7.5, False),
        (6500.0, 0.0127 / 2, False),
        (100.0, 0.0127 / 18, True),
        (40.0, 0.0127 / 18, False),
    ):
        cause = Cause("CL", ["mach"], [term], "step", {"p_value": 0.0, "F": f_stat}, 0.0127, size=0.0127)
        judge([cause], {"CL": res}, data, [np.array([floor])])
        v = cause.verdict
        assert not v["accepted"] and "one condition only (10000/0.5/0)" in v["reason"], v["reason"]
        assert v["unconfirmed"] is unconfirmed, (f_stat, floor, v)
        assert ("a discrepancy at one condition needs" in v["reason"]) is (f_stat < 60.0), v["reason"]


def test_a_strong_cause_at_one_condition_only_that_its_own_repeats_refute_is_no_discrepancy():
    """The lift step of the test above, 18 times its floor at an F of 100 (the held-out rule's F of 300 not
    reached), its one condition above the step flown three times. When the three logs agree, each one left
    out is predicted by the other two: the cause is named. When the step
    is one log's alone (one flight's turbulence: null 8,700,158, an A320 drag in gear x flap at its
    flap-15 condition, 18 times its floor, x0.876 with each log left out), each log left out is predicted
    worse with it than without: its repeats refute it, and it is not a discrepancy whose cause the data
    cannot confirm."""
    import pandas as pd

    from diagnose.causes import Cause
    from diagnose.config import DEFAULTS
    from diagnose.stepwise import StepwiseResult
    from diagnose.terms import Term
    from diagnose.verdict import judge

    rng = np.random.default_rng(4)
    conds = [("2000/0.2/30", 0.2, 0.0), ("2000/0.3/0", 0.3, 0.0), ("10000/0.3/0", 0.3, 0.0)]
    for offsets, accepted, unconfirmed in (((0.0127,) * 3, True, False), ((0.0381, 0.0, 0.0), False, False)):
        logs = conds + [("10000/0.5/0", 0.5, o) for o in offsets]
        data = pd.concat(
            [
                pd.DataFrame(
                    {
                        "condition": c,
                        "log": i,
                        "mach": m + rng.normal(0, 0.001, 400),
                        "r_CL": o + rng.normal(0, 0.0015, 400),
                    }
                )
                for i, (c, m, o) in enumerate(logs)
            ],
            ignore_index=True,
        )
        term = Term("smooth", ("mach",), (0.2, 0.3, 0.5))
        x = np.column_stack([np.ones(len(data)), term.design(data)])
        beta = np.linalg.lstsq(x, data.r_CL.to_numpy(), rcond=None)[0]
        res = StepwiseResult("CL", [term], beta, {}, [], 0.0, 0.0, len(data))
        cause = Cause("CL", ["mach"], [term], "step", {"p_value": 0.0, "F": 100.0}, 0.0127, size=0.0127)
        judge([cause], {"CL": res}, data, [np.array([0.0127 / 18])])
        v = cause.verdict
        assert v["accepted"] is accepted and v["unconfirmed"] is unconfirmed, (offsets, v)
        if not accepted:
            assert "one condition only (10000/0.5/0)" in v["reason"] and v["replicate_gain"] < DEFAULTS.refuted_gain, v


def _offsets(seed: int, f: float = 50.0, over_floor: float = 4.0, kind: str = "aero") -> dict:
    """A null: CD at four conditions (Mach 0.3 twice, 0.4, 0.5), three logs each with its own offset
    (one flight's turbulence) and white noise, and a line in Mach fitted to it as a cause (F ``f``, its
    floor ``1 / over_floor`` of its size): its verdict."""
    import pandas as pd

    from diagnose.causes import Cause
    from diagnose.stepwise import StepwiseResult
    from diagnose.terms import Term
    from diagnose.verdict import judge

    rng = np.random.default_rng(seed)
    frames = []
    for i, (c, m) in enumerate([("5000/0.3/0", 0.3), ("5000/0.3/15", 0.3), ("10000/0.4/0", 0.4), ("10000/0.5/0", 0.5)]):
        for k in range(3):
            frames.append(
                pd.DataFrame(
                    {
                        "condition": c,
                        "log": 3 * i + k,
                        "mach": m + rng.normal(0, 0.002, 300),
                        "r_CD": rng.normal(0, 0.0015) + rng.normal(0, 0.002, 300),
                    }
                )
            )
    data = pd.concat(frames, ignore_index=True)
    term = Term("linear", ("mach",), centers=(0.3,), ranges=((0.3, 0.5),))
    beta = np.linalg.lstsq(np.column_stack([np.ones(len(data)), term.design(data)]), data.r_CD.to_numpy(), rcond=None)[
        0
    ]
    res = StepwiseResult("CD", [term], beta, {}, [], 0.0, 0.0, len(data))
    size = float(np.ptp(term.design(data) @ beta[1:]))
    cause = Cause("CD", ["mach"], [term], "linear", {"p_value": 0.0, "F": f}, size, size=size, kind=kind)
    judge([cause], {"CD": res}, data, [np.array([size / over_floor])])
    return cause.verdict


def test_the_held_out_decision_is_the_replicate_gain_calibrated_on_nulls():
    """One decision on held-out data: each log left out in turn, predicted from the others, its own
    condition's repeats among them, at least ``replicate_gain`` (x1.2, above the x1.164 the largest of
    the candidates of 300 simulated null flights without sensor errors reached). A line in Mach fitted
    to the offsets of a few flights gains x1.11 with each condition left out, which a decision by
    conditions left out (at x1.05) would take for a cause; with each log left out it gains x1.04, and is
    not named."""
    from diagnose.config import DEFAULTS

    assert DEFAULTS.replicate_gain == 1.2
    v = _offsets(11)
    assert v["holdout_gain"] > 1.1 and v["replicate_gain"] < 1.05, v
    assert not v["accepted"] and f"needs x{DEFAULTS.replicate_gain}" in v["reason"], v["reason"]


def test_a_strong_candidate_only_held_out_data_reject_is_a_discrepancy_whose_cause_is_not_confirmed():
    """Seed 8,300,209: a Cm step in the elevator hidden in the stock 737, flown in 3 ft/s, removed
    74 % of the Cm residual (F 482, 10.6 times its floor beyond instrument errors), but its shape did not
    predict the logs left out (x0.98). A candidate that held-out data alone reject, with an F of
    ``held_out_f`` (300; the nulls' largest such was 73) and 3 times its floor, is a discrepancy, its cause
    not confirmed: named so, kept out of the extension (seed 8,400,252, a CL table in the elevator at
    F 358 and 5.8 times its floor, is one).
    Below either bound it is rejected as before, and so is an instrument error's signature (seed
    8,400,184 named one so, and the benchmark took it for an aerodynamic discrepancy)."""
    from diagnose.config import DEFAULTS

    held_out_f = DEFAULTS.held_out_f
    for over in (12.0, 3.5):
        v = _offsets(11, f=held_out_f, over_floor=over)
        assert v["replicate_gain"] < 1.05 and not v["accepted"] and v["unconfirmed"], (over, v)
        assert "a discrepancy all the same (F = 300, " in v["reason"], v["reason"]
    for f, over, kind in ((0.9 * held_out_f, 12.0, "aero"), (held_out_f, 2.5, "aero"), (held_out_f, 12.0, "sensor")):
        v = _offsets(11, f=f, over_floor=over, kind=kind)
        assert not v["accepted"] and not v["unconfirmed"] and "all the same" not in v["reason"], (f, over, kind, v)


def _four_conditions(seed: int, signal, offset: float, noise: float):
    """Mach 0.3 twice, 0.4 and 0.5, three logs each of 300 samples: ``r_CL`` is ``signal(mach flown,
    mach)`` plus an offset per log (the turbulence of one flight, std ``offset``) and white noise."""
    import pandas as pd

    rng = np.random.default_rng(seed)
    frames = []
    for i, (c, m) in enumerate([("5000/0.3/0", 0.3), ("10000/0.3/0", 0.3), ("10000/0.4/0", 0.4), ("10000/0.5/0", 0.5)]):
        for k in range(3):
            mach = m + rng.normal(0, 0.002, 300)
            frames.append(
                pd.DataFrame(
                    {
                        "condition": c,
                        "log": 3 * i + k,
                        "mach": mach,
                        "r_CL": signal(m, mach) + rng.normal(0, offset) + rng.normal(0, noise, 300),
                    }
                )
            )
    return pd.concat(frames, ignore_index=True)


def _repeats(step: float, seed: int):
    """CL at four conditions (Mach 0.3 twice, 0.4 and 0.5), three logs each with its own offset (the
    turbulence of one flight) and white noise; ``step`` added at Mach 0.5 alone. A smooth term in
    Mach fitted to it (knots at the Mach numbers flown), as the cause."""
    from diagnose.terms import Term

    data = _four_conditions(seed, lambda m, mach: step * (m == 0.5), 0.0006, 0.002)
    return _mach_cause(data, Term("smooth", ("mach",), (0.3, 0.4, 0.5)), "table", 500.0)


def _mach_cause(data, term, shape: str, f: float):
    """``term`` fitted to ``r_CL`` of ``data``: the cause, its stepwise result, the data."""
    from diagnose.causes import Cause
    from diagnose.stepwise import StepwiseResult

    beta = np.linalg.lstsq(np.column_stack([np.ones(len(data)), term.design(data)]), data.r_CL.to_numpy(), rcond=None)[
        0
    ]
    res = StepwiseResult("CL", [term], beta, {}, [], 0.0, 0.0, len(data))
    size = float(np.ptp(term.design(data) @ beta[1:]))
    return Cause("CL", ["mach"], [term], shape, {"p_value": 0.0, "F": f}, size, size=size), res, data


def test_repeats_at_a_condition_confirm_what_the_other_conditions_cannot():
    """A lift change at the one Mach number between the others flown (seeds 3,800,066
    and 3,800,124: a table and a late onset in Mach on the A320, 3 and 18 times the floor, x1.03 and
    x1.004 with each condition left out, "no significant discrepancy") is named: each log,
    predicted from the others, its own condition's repeats among them, gains ``replicate_gain``, where
    the conditions left out in turn refute it (x0.64). Where only per-flight offsets and noise are
    there, the same term is not."""
    from diagnose.config import DEFAULTS
    from diagnose.verdict import judge

    cause, res, data = _repeats(0.006, 1)
    judge([cause], {"CL": res}, data, [np.array([cause.size / 4])])
    v = cause.verdict
    assert v["holdout_gain"] < 1.0 and v["replicate_gain"] >= DEFAULTS.replicate_gain, v
    assert v["accepted"], v["reason"]
    for seed in range(2, 8):
        cause, res, data = _repeats(0.0, seed)
        judge([cause], {"CL": res}, data, [np.array([cause.size / 4])])
        v = cause.verdict
        assert v["replicate_gain"] < DEFAULTS.replicate_gain and not v["accepted"], (
            seed,
            v["replicate_gain"],
            v["reason"],
        )


def test_a_table_in_mach_between_the_conditions_flown_is_named(tmp_path):
    """A random 8-knot table in Mach (seed 3,000,041 of the detection curve: CL up to
    0.009, 4.4 times the floor, 3 ft/s turbulence, our 737): Mach 0.2 and 0.5, each flown at one
    condition, were predicted by extrapolation and refuted it (x0.81 pooled); the answer was
    "no significant discrepancy"."""
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT

    doc = diagnose_overlay(tmp_path, "lift_mach_table.xml", DEFAULT_AIRCRAFT, DIAG_MATRIX, 3000041)
    aero = discrepancies(doc)
    assert aero and (aero[0]["coefficient"], aero[0]["variables"][0]) == ("CL", "mach"), doc["summary"]
    # the matrix flies flap 30 at Mach 0.2 only: the report says how much of the cause the flap could make
    assert doc["flown_together"]["groups"] == [
        {"flap_deg": [30.0], "mach": [0.2]},
        {"flap_deg": [0.0], "mach": [0.3, 0.5]},
    ], doc["flown_together"]
    lines = doc["summary"].splitlines()
    first = next(i for i, t in enumerate(lines) if t.startswith("1. CL vs mach"))
    assert "which an effect of flap_deg would make alike" in lines[first + 1], lines[first + 1]
    assert any(t.startswith("Caution: flap and Mach flown together") for t in lines[:first])


def test_flap_and_mach_flown_together_are_told_and_the_benchmark_matrices_fly_them_apart(tmp_path):
    """Where the flap angles and the Mach numbers they are flown at fall into sets that share neither, an
    effect of one fits as the other over the data (:mod:`diagnose.flap_mach`); the detection curve's
    matrices fly a flap angle at another's Mach number."""
    from benchmarks.detection_curve import A320, OUR_737
    from campaign.simulation.matrix import load_matrix
    from diagnose.flap_mach import flown_together, level_share

    old = [(2000, 0.3, 0), (10000, 0.3, 0.0), (10000, 0.5, 0), (2000, 0.2, 30)]
    told = flown_together(old)
    assert told["groups"] == [{"flap_deg": [30.0], "mach": [0.2]}, {"flap_deg": [0.0], "mach": [0.3, 0.5]}]
    assert "flap 30 deg only at Mach 0.2; flap 0 deg only at Mach 0.3, 0.5" in told["text"]
    assert flown_together([(2000, 0.3, 0), (10000, 0.3, 30), (2000, 0.2, 30)]) is None  # Mach 0.3 at both
    assert flown_together([(2000, 0.3, 0), (10000, 0.5, 0)]) is None  # one flap angle
    # three flap angles: 0 and 15 share Mach 0.4, flap 30 is flown at Mach 0.2 alone
    three = flown_together([(2000, 0.3, 0), (5000, 0.4, 0), (5000, 0.4, 15), (2000, 0.2, 30)])
    assert three["groups"] == [{"flap_deg": [30.0], "mach": [0.2]}, {"flap_deg": [0.0, 15.0], "mach": [0.3, 0.4]}]
    # imported logs: a flap channel's mean reads 0.04 in one log and 0.06 in the next, one setting
    assert flown_together([(2000, 0.3, 0.04), (2000, 0.4, 0.06), (2000, 0.2, 30.1)])["groups"][1]["flap_deg"] == [0.0]
    assert flown_together([(2000, 0.3, 0.04), (2000, 0.4, 0.06)]) is None
    # a level at flap 30 is all a level per set; a slope over the clean Mach numbers is none of it
    log = np.repeat(np.arange(4), 50)
    mach = np.array([0.3, 0.3, 0.5, 0.2])[log]
    assert level_share(np.where(log == 3, 0.01, 0.0), log, old, told) == pytest.approx(1.0)
    slope = np.where(log < 3, mach - mach[log < 3].mean(), 0.0)
    assert level_share(slope, log, old, told) == pytest.approx(0.0, abs=1e-12)

    def points(text: str) -> list[tuple]:
        (tmp_path / "m.toml").write_text(text)
        return [(p.alt_ft, p.mach, p.flap_deg) for p in load_matrix(tmp_path / "m.toml").points]

    for name, text in (("our 737", OUR_737), ("A320", A320)):
        assert flown_together(points(text)) is None, name
    assert flown_together(points(DIAG_MATRIX)) is not None  # the tests' own matrix, as the benchmark's was


def test_two_collinear_causes_that_cancel_gain_nothing_on_held_out_data():
    """Two terms on nearly collinear variables, fitted with large opposite coefficients to a small
    residual (the stock 737's CD against CL and against alpha x elevator in 3 ft/s turbulence, each
    0.075 in size where together they explained 0.0002): each cause's held-out gain is that of the
    terms with it over the terms refitted without it, not of removing its part alone from the joint
    fit (which gave x17 to both); and a real effect beside them keeps its gain."""
    import pandas as pd

    from diagnose.causes import Cause
    from diagnose.stepwise import StepwiseResult
    from diagnose.terms import Term
    from diagnose.verdict import holdout_gain

    rng = np.random.default_rng(1)
    frames = []
    for i in range(4):
        a = rng.uniform(0, 1, 500) + i
        frames.append(
            pd.DataFrame(
                {"condition": f"c{i}", "log": i, "a": a, "b": a + rng.normal(0, 0.01, 500), "g": rng.uniform(0, 1, 500)}
            )
        )
    data = pd.concat(frames, ignore_index=True)
    data["r_CD"] = 0.002 * (data["g"] - 0.5) + rng.normal(0, 0.0003, len(data))
    terms = [Term("linear", (v,), centers=(0.0,), ranges=((-np.inf, np.inf),)) for v in ("a", "b", "g")]
    x = np.column_stack([np.ones(len(data))] + [t.design(data) for t in terms])
    beta = np.linalg.lstsq(x, data.r_CD.to_numpy(), rcond=None)[0]
    beta[1], beta[2] = 0.04, -0.04  # cancelling: the fit is nearly the same, each part large
    res = StepwiseResult("CD", terms, beta, {}, [], 0.0, 0.0, len(data))
    for t, v in zip(terms[:2], ("a", "b")):
        size = float(np.ptp(t.design(data)[:, 0] * 0.04))
        gain, _, by = holdout_gain(res, Cause("CD", [v], [t], "linear", {"p_value": 0.0}, size / 2, size=size), data)
        assert gain < 1.02, (v, gain, by)
    g = terms[2]
    gain, _, _ = holdout_gain(res, Cause("CD", ["g"], [g], "linear", {"p_value": 0.0}, 0.001, size=0.002), data)
    assert gain > 2.0, gain


def test_the_first_of_two_collinear_causes_is_tested_against_the_terms_before_it():
    """A drag dip in alpha on the stock 737 in 3 ft/s turbulence (seed 3,000,174: 19 times
    the floor) was fitted by smooth(alpha) and then quadratic(CL), nearly the same variable: each
    cause, tested against the other, gained nothing on held-out data (x0.69 and x0.90) and the answer
    was "no significant discrepancy". The first to enter is also tested against the terms that entered
    before it (none), the stepwise search's own order; the larger gain stands. The second still gains
    nothing."""
    import pandas as pd

    from diagnose.causes import Cause
    from diagnose.stepwise import StepwiseResult
    from diagnose.terms import Term
    from diagnose.verdict import holdout_gain

    rng = np.random.default_rng(3)
    frames = []
    for i in range(4):
        a = rng.uniform(0, 2, 500) + 2 * i
        frames.append(pd.DataFrame({"condition": f"c{i}", "log": i, "a": a, "b": a + rng.normal(0, 0.3, 500)}))
    data = pd.concat(frames, ignore_index=True)
    data["r_CD"] = 0.002 * data["a"] + rng.normal(0, 0.001, len(data))
    terms = [Term("linear", (v,), centers=(0.0,), ranges=((-np.inf, np.inf),)) for v in ("a", "b")]
    x = np.column_stack([np.ones(len(data))] + [t.design(data) for t in terms])
    beta = np.linalg.lstsq(x, data.r_CD.to_numpy(), rcond=None)[0]
    res = StepwiseResult("CD", terms, beta, {}, [], 0.0, 0.0, len(data))
    first = Cause("CD", ["a"], [terms[0]], "linear", {"p_value": 0.0}, 0.008, size=0.016)
    gain, _, by = holdout_gain(res, first, data)
    assert gain > 1.5, (gain, by)
    size = float(np.ptp(terms[1].design(data) @ res.term_beta(terms[1])))
    second = Cause("CD", ["b"], [terms[1]], "linear", {"p_value": 0.0}, size / 2, size=size)
    gain, _, by = holdout_gain(res, second, data)
    assert gain < 1.02, (gain, by)
    # one of a cancelling pair (a vane scale's moment against alpha beside the moment against CL, 466
    # times its floor, on a stock-737 null): its part of the joint fit is 20 times what it is alone,
    # and is not tested alone
    beta[1], beta[2] = 0.04, -0.038
    pair = StepwiseResult("CD", terms, beta, {}, [], 0.0, 0.0, len(data))
    size = float(np.ptp(terms[0].design(data)[:, 0] * 0.04))
    gain, _, by = holdout_gain(
        pair, Cause("CD", ["a"], [terms[0]], "linear", {"p_value": 0.0}, size / 2, size=size), data
    )
    assert gain < 1.5, (gain, by)


def test_a_lift_dip_in_alpha_one_condition_refutes_is_named(tmp_path):
    """CL changed by +0.0134 times a dip over alpha (seed 3,000,203 of the detection curve, our 737, 3 ft/s
    turbulence, 9 times the floor): fitted 3.5 times its floor beyond instrument errors, x1.31 on
    held-out data pooled, but x0.69 at one condition left out. No single condition vetoes a cause: the
    pooled gain decides."""
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT

    doc = diagnose_overlay(tmp_path, "lift_alpha_dip.xml", DEFAULT_AIRCRAFT, DIAG_MATRIX, 3000203)
    aero = discrepancies(doc)
    assert aero and (aero[0]["coefficient"], aero[0]["variables"][0]) == ("CL", "alpha_deg"), doc["summary"]


def test_a_moment_table_in_alpha_that_grows_with_mach_is_named_with_both(tmp_path):
    """A random 7-knot table in alpha times (Mach - 0.2) / 0.3 in Cm (seed 3,600,081 of
    the detection curve: 5.7 times the floor, 3 ft/s, our 737). With no smooth term in alpha that
    varies with Mach among the candidates, it was named "Cm vs mach": the right coefficient, not
    the shape."""
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT

    doc = diagnose_overlay(tmp_path, "moment_alpha_mach_table.xml", DEFAULT_AIRCRAFT, DIAG_MATRIX, 3600081)
    aero = discrepancies(doc)
    assert aero and aero[0]["coefficient"] == "Cm" and set(aero[0]["variables"]) >= {"alpha_deg", "mach"}, doc[
        "summary"
    ]


def test_a_cause_held_out_conditions_confirm_comes_before_one_no_other_condition_can_test(tmp_path):
    """Our 737 in 3 ft/s with CD up to +0.014 in a dip about Mach 0.34, beside an engine deck 6.1 % long
    (seed 2,000,083, 13 times its floor). The thrust scale was named at +0.056, and the rest of it
    is largest in the one flap-30 condition, flown at Mach 0.2 on the most thrust over dynamic pressure:
    "CD vs flap" came 159 times its floor, "CD vs mach" 147 and x3.2 on held-out conditions. No other
    condition flies flap 30: only its repeats confirm the flap term, and it stands for whatever else sets
    that condition apart. The cause the held-out conditions confirm is the answer: with the fit holding
    the highest-alpha condition, the drag is named "CD vs mach, alpha_deg", Mach first."""
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT

    doc = diagnose_overlay(
        tmp_path,
        "drag_mach_dip.xml",
        DEFAULT_AIRCRAFT,
        DIAG_MATRIX,
        2000083,
        channels="[channels.thrust_lbf]\nscale = 1.0612165590313636\n",
    )
    aero = [c for c in doc["causes"] if c["kind"] == "aero"]
    assert aero and aero[0]["coefficient"] == "CD" and aero[0]["variables"][0] == "mach", doc["summary"]
    assert "flap_deg" not in aero[0]["variables"], doc["summary"]
    assert np.isfinite(aero[0]["verdict"]["holdout_gain"])
    assert discrepancies(doc)[0] is aero[0]


def test_a_cause_the_replacement_splits_in_two_is_named(tmp_path):
    """A monotone 7-knot table in alpha times (Mach - 0.2) / 0.3 in Cm, down to -0.013, in our 737's data
    in 3 ft/s (seed 2,000,126, 3.5 times its floor). The search chose smooth(alpha) and
    alpha x Mach: one cause. The sequential replacement put quadratic(Mach) in alpha x Mach's place,
    a closer fit with fewer columns, and the one cause became two, each too small to gain on held-out
    logs (x1.10 and x1.20, needing x1.2): nothing was named. A split is two claims, each to stand on
    its own; when a part falls, the search runs again without splitting, and the whole reading is
    kept if it names a discrepancy there. (Forbidding every split lost a lift table in Mach on the
    stock 737 whose parts both stand: ``test_the_replacement_splits_a_term_that_stood_for_two_causes``.)"""
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT

    doc = diagnose_overlay(tmp_path, "moment_alpha_mach_monotone.xml", DEFAULT_AIRCRAFT, DIAG_MATRIX, 2000126)
    aero = discrepancies(doc)
    assert aero and aero[0]["coefficient"] == "Cm" and set(aero[0]["variables"]) >= {"alpha_deg", "mach"}, doc[
        "summary"
    ]
    assert "Cm" in doc["whole_readings"] and "read whole" in doc["summary"]


def _slope(seed: int):
    """CL growing linearly with Mach over four conditions (three logs each, offsets and noise), and
    a linear term in Mach fitted to it, as the cause."""
    from diagnose.terms import Term

    data = _four_conditions(seed, lambda m, mach: 0.2 * (mach - 0.4), 0.0003, 0.001)
    return _mach_cause(data, Term("linear", ("mach",), (), (0.4,), ((0.29, 0.51),)), "linear", 5000.0)


def test_a_cause_an_error_measured_and_left_uncorrected_makes_whole_is_that_error():
    """A cause 20 times its floor that gains on held-out data, and that instrument errors within reach
    could make whole, is a discrepancy all the same ("unconfirmed"), unless the data compatibility
    measured the one error that makes it, 2 standard errors from none or more, left it uncorrected,
    and the cause needs it within 2 of that measurement: then it is rejected as that error. Beside a
    cause the errors cannot make, such an error changes nothing (the verdict once failed there)."""
    from diagnose.verdict import judge

    vane = {
        "channel": "alpha_deg",
        "error": "bias",
        "needs": 0.271,
        "needs_se": 0.13,
        "se": 0.104,
        "left": 0.257,
        "explains_pct": 100.0,
    }
    applied = {**vane, "left": 0.0, "needs_se": 2.6}
    verdicts = {}
    for name, alt, made in (("measured", vane, True), ("corrected", applied, True), ("beside", vane, False)):
        cause, res, data = _slope(3)
        floor = cause.size / 20
        reach = {"made": cause.size if made else 0.0, "left": floor / 2 if made else cause.size, "alternatives": [alt]}
        judge([cause], {"CL": res}, data, [np.array([floor])], reach=[reach])
        verdicts[name] = cause.verdict
        assert cause.verdict["holdout_gain"] >= 1.5, cause.verdict
    assert not verdicts["measured"]["accepted"] and not verdicts["measured"]["unconfirmed"], verdicts["measured"]
    assert "left it uncorrected" in verdicts["measured"]["reason"]
    assert verdicts["corrected"]["unconfirmed"] and "a discrepancy all the same" in verdicts["corrected"]["reason"]
    assert verdicts["beside"]["accepted"], verdicts["beside"]["reason"]


def test_a_cause_a_vane_error_measured_whole_but_split_makes_is_that_error_whatever_is_left():
    """Null 9,200,256 (stock 737, 3 ft/s): a +0.282 deg vane bias was measured as +0.097 +- 0.12 deg and a
    4.0 +- 2.1 % scale, each short of 2 standard errors, together 5.5 from none; the drag in alpha x Mach it made
    was named, 1.8 times its floor beyond what the errors within reach make. When the data compatibility measured
    a channel's errors together ``measured_channel_se`` (``compat.apply_z``) standard errors from none, left
    them, and one of them alone makes 90 % of the cause at a size within 2 standard errors of its measurement, the
    cause is that error. Re-flown effects 3-10 times their floor whose named cause a vane error could make (11 of
    16 a margin rule would have lost) had their vane's errors 0.3-1.8 from none together: those stay named."""
    from diagnose.config import DEFAULTS
    from diagnose.verdict import judge

    assert DEFAULTS.measured_channel_se == DEFAULTS.compat.apply_z
    bias = {
        "channel": "alpha_deg",
        "error": "bias",
        "needs": 0.268,
        "needs_se": 1.48,
        "se": 0.116,
        "left": 0.097,
        "explains_pct": 99.1,
    }
    verdicts = {}
    for name, joint in (("measured together", 5.54), ("not measured", 1.8)):
        cause, res, data = _slope(3)
        floor = cause.size / 13
        reach = {"made": 0.89 * cause.size, "left": 1.8 * floor, "alternatives": [{**bias, "channel_left_se": joint}]}
        judge([cause], {"CL": res}, data, [np.array([floor])], reach=[reach])
        verdicts[name] = cause.verdict
        assert cause.verdict["replicate_gain"] >= 1.5, cause.verdict
    v = verdicts["measured together"]
    assert not v["accepted"] and not v["unconfirmed"], v
    assert "errors together 5.5 standard errors from none" in v["reason"] and "that error" in v["reason"], v["reason"]
    assert verdicts["not measured"]["accepted"], verdicts["not measured"]["reason"]


def _transit(bump: float, seed: int):
    """Four conditions, three gear extensions each: 200 samples gear up, 100 in the gear's travel,
    200 gear down; ``r_CL`` a bump of ``bump`` during the travel (at gear_norm 0.5, width 0.13),
    an offset per log (one flight's turbulence) and white noise. A smooth term in gear_norm fitted
    to it, as the cause."""
    import pandas as pd

    from diagnose.terms import Term

    rng = np.random.default_rng(seed)
    gear = np.concatenate([np.zeros(200), np.linspace(0.0, 1.0, 100), np.ones(200)])
    frames = []
    for i, c in enumerate(["5000/0.3/0", "10000/0.3/0", "10000/0.4/0", "10000/0.5/0"]):
        for k in range(3):
            frames.append(
                pd.DataFrame(
                    {
                        "condition": c,
                        "log": 3 * i + k,
                        "gear_norm": gear,
                        "r_CL": bump * np.exp(-0.5 * ((gear - 0.5) / 0.13) ** 2)
                        + rng.normal(0, 0.0006)
                        + rng.normal(0, 0.002, gear.size),
                    }
                )
            )
    data = pd.concat(frames, ignore_index=True)
    term = Term("smooth", ("gear_norm",), (0.0, 0.25, 0.5, 0.75, 1.0))
    beta = np.linalg.lstsq(np.column_stack([np.ones(len(data)), term.design(data)]), data.r_CL.to_numpy(), rcond=None)[
        0
    ]
    from diagnose.causes import Cause
    from diagnose.stepwise import StepwiseResult

    res = StepwiseResult("CL", [term], beta, {}, [], 0.0, 0.0, len(data))
    size = float(np.ptp(term.design(data) @ beta[1:]))
    return Cause("CL", ["gear_norm"], [term], "bump", {"p_value": 0.0, "F": 50.0}, size, size=size), res, data


def test_a_cause_that_acts_during_the_gear_travel_alone_is_judged_where_it_departs():
    """A lift bump during the gear's travel (seeds 6,200,038 and 2,000,181: 6.6 and 7.2
    times the floor, x1.16 and x1.08 with each log left out, "no significant discrepancy") acts in a
    fifth of each gear extension: counted over the whole log, its held-out gain is diluted below
    ``replicate_gain``. Counted where it departs from the model, it is ``departs_gain`` or more, and it is
    named; the same term fitted to per-flight offsets and noise alone is not."""
    from diagnose.config import DEFAULTS
    from diagnose.verdict import judge

    replicate_gain, departs_gain = DEFAULTS.replicate_gain, DEFAULTS.departs_gain
    cause, res, data = _transit(0.004, 1)
    judge([cause], {"CL": res}, data, [np.array([cause.size / 4])])
    v = cause.verdict
    assert v["replicate_gain"] < replicate_gain <= departs_gain <= v["replicate_gain_where_departs"], v
    assert v["accepted"], v["reason"]
    for seed in range(2, 10):
        cause, res, data = _transit(0.0, seed)
        judge([cause], {"CL": res}, data, [np.array([cause.size / 4])])
        v = cause.verdict
        assert v["replicate_gain_where_departs"] < departs_gain and not v["accepted"], (seed, v)
        assert f"where it departs, needs x{departs_gain}" in v["reason"], v["reason"]


def test_a_constant_the_intercept_takes_back_is_not_a_cause_s_peak():
    """A term whose column nearly holds a constant over the data (Mach about 0 where the data sit at
    0.5; elevator x Mach where each condition trims at its own elevator) carries a constant that the
    intercept takes back ("CL vs elevator_deg, mach" was reported with a peak of 83,000): the cause's
    peak, curve and contribution are its departure over the data, without that constant."""
    import pandas as pd

    from diagnose.causes import name_causes
    from diagnose.stepwise import Lags, StepwiseResult
    from diagnose.terms import Term
    from diagnose.verdict import contribution

    rng = np.random.default_rng(3)
    mach = 0.5 + 0.003 * np.sin(np.linspace(0, 12, 800))
    data = pd.DataFrame(
        {
            "condition": "10000/0.5/0",
            "log": np.repeat([0, 1], 400),
            "mach": mach,
            "r_CL": 10.0 * (mach - 0.5) + rng.normal(0, 0.001, 800),
        }
    )
    term = Term("linear", ("mach",), centers=(0.0,), ranges=((0.0, 1.0),))
    x = np.column_stack([np.ones(len(data)), term.design(data)])
    res = StepwiseResult(
        "CL", [term], np.linalg.lstsq(x, data.r_CL.to_numpy(), rcond=None)[0], {}, [], 0.0, 0.0, len(data)
    )
    assert abs(res.beta[1] * 0.5) > 4  # the term holds about 5, the intercept about -5
    (cause,) = name_causes({"CL": res}, data, Lags(data["log"].to_numpy()))
    assert 0.05 < cause.size < 0.07 and cause.peak <= cause.size, (cause.peak, cause.size)
    assert np.max(np.abs(cause.curve["dCL"])) <= cause.size
    assert np.max(np.abs(contribution(res, cause, data))) <= cause.size


def test_a_refined_error_carries_the_errors_the_kinematics_estimated_with_it():
    """The kinematics' vane bias and scale trade at the trim alphas (correlation -0.95). When the CL
    and Cm residuals refine the scale to none, the bias estimated with it follows to its value given
    that scale, and at 0.75 standard errors it is no longer applied. Left where it was, -0.09 deg of
    bias made a "CD vs flap, alpha" 3.4 times its floor on our 737's null 7,900,339 (x0.20 on held-out
    logs with the bias); an error the scale hardly correlates with (0.05) moves by a quarter of its
    standard error and stays applied."""
    from types import SimpleNamespace

    from diagnose.arbitration import residual_refinement
    from identify.compat import CompatResult, Parameter

    bias = Parameter("alpha_deg", "bias", "deg", -0.0905, 0.015)
    scale = Parameter("alpha_deg", "scale", "-", 0.02996, 0.0054)
    az = Parameter("az_fps2", "bias", "ft/s^2", 0.05, 0.005)
    sd = np.array([0.015, 0.0054, 0.005])
    corr = np.array([[1.0, -0.95, 0.0], [-0.95, 1.0, 0.05], [0.0, 0.05, 1.0]])
    compat = CompatResult(
        [bias, scale, az], covariance=[(["alpha_deg.bias", "alpha_deg.scale", "az_fps2.bias"], corr * np.outer(sd, sd))]
    )
    assert bias.applied and scale.applied and az.applied

    def cause(coefficient):
        return SimpleNamespace(
            kind="aero",
            coefficient=coefficient,
            size=0.01,
            evidence={"p_value": 1e-30},
            verdict={"noise_floor": 0.001, "replicate_gain": 2.0},
        )

    causes = [cause("CL"), cause("Cm")]
    reach = [
        {"alternatives": [{"channel": "alpha_deg", "error": "scale", "needs": n, "explains_pct": 95.0}]}
        for n in (-0.031, -0.029)
    ]
    refined = residual_refinement(compat, causes, reach)
    assert refined is not None and refined.name == "alpha_deg.scale"
    got = {p.name: p for p in refined.compat.parameters}
    moved = -0.0905 + (-0.95 * 0.015 / 0.0054) * (got["alpha_deg.scale"].estimate - 0.02996)
    assert got["alpha_deg.bias"].estimate == pytest.approx(moved) and abs(moved) < 0.015
    assert not got["alpha_deg.bias"].applied and got["alpha_deg.bias"].se == 0.015
    az_moved = 0.05 + (0.05 * 0.005 / 0.0054) * (got["alpha_deg.scale"].estimate - 0.02996)
    assert got["az_fps2.bias"].applied and got["az_fps2.bias"].estimate == pytest.approx(az_moved)
    assert abs(az_moved - 0.05) < 0.3 * 0.005


def _breakpoints(xml: str, lookup: str | None = None) -> list[float]:
    """The breakpoints of an effect overlay's table: its rows, or (``lookup="column"``) its columns."""
    import xml.etree.ElementTree as ET

    rows = [r.split() for r in ET.fromstring(xml).find(".//tableData").text.strip().splitlines()]
    return [float(x) for x in rows[0]] if lookup == "column" else [float(r[0]) for r in rows[lookup == "row" :]]


def test_the_grammar_draws_an_effect_on_the_range_it_is_given_and_nothing_else_changes():
    """The stock A320 trims its elevator at -25 to -2 deg and our 737 at -3 to 3: a shape drawn on our 737's
    range acts on the A320 in a few samples of one condition. Given the aircraft's range, the table spans it,
    and the draw (shape, its parameters, sign, size) is the same as on the default range."""
    mine = draw(np.random.default_rng(7), variables=("elevator_deg",))
    theirs = draw(np.random.default_rng(7), variables=("elevator_deg",), ranges={"elevator_deg": (-25.0, -2.0)})
    assert (theirs.description, theirs.size) == (mine.description, mine.size)
    assert _breakpoints(mine.xml)[::40] == [-3.0, 3.0] and _breakpoints(theirs.xml)[::40] == [-25.0, -2.0]
    pair = draw(np.random.default_rng(7), variables=("alpha_deg", "mach"), ranges={"mach": (0.3, 0.5)})
    assert _breakpoints(pair.xml, "column")[::4] == [0.3, 0.5] and _breakpoints(pair.xml, "row")[::40] == [1.0, 10.0]
    assert "(mach - 0.3)/0.2" in pair.description


def test_the_benchmark_draws_on_the_range_each_aircraft_flies(tmp_path):
    """The detection curve's ranges are the stock A320's as flown over its matrix, not our 737's: its
    elevator trims below -2 deg, it flies Mach 0.3 to 0.5 and its flap at 0 and 15 deg."""
    import jsbsim

    from benchmarks.detection_curve import A320, flown_ranges

    got = flown_ranges(str(Path(jsbsim.get_default_root_dir()) / "aircraft" / "A320"), A320)
    assert -27 < got["elevator_deg"][0] < -20 and -4 < got["elevator_deg"][1] < -1, got
    assert got["mach"] == pytest.approx((0.3, 0.5), abs=0.01) and got["flap_deg"] == (0.0, 15.0), got
    assert got["gear_norm"] == (0.0, 1.0) and 0 < got["alpha_deg"][0] < got["alpha_deg"][1] < 12, got


def test_what_an_effect_leaves_beyond_one_variable_shows_a_second_only_where_the_data_vary_it():
    """The benchmark's "hit as flown" (benchmarks/detection_curve.py): a function of one variable leaves
    nothing beyond it; a second variable that changes the effect where the first overlaps across logs
    leaves its part, even where the first is one value (gear down) in every log."""
    from benchmarks.detection_curve import left_beyond

    rng = np.random.default_rng(3)
    logs = [(m, rng.uniform(lo, lo + 5, 2000)) for m, lo in ((0.3, 5.0), (0.4, 2.0), (0.5, 0.0))]
    mach = np.concatenate([np.full(len(a), m) for m, a in logs])
    alpha = np.concatenate([a for _, a in logs])
    ramp = np.clip(alpha - 4.0, 0.0, None)
    assert left_beyond(0.01 * ramp, alpha) < 0.01 * np.ptp(0.01 * ramp)
    # the same ramp times a Mach factor: the logs overlap in alpha from 5 to 7 deg at two Mach numbers
    assert left_beyond(0.01 * ramp * mach / 0.3, alpha) > 0.2 * np.ptp(0.01 * ramp * mach / 0.3 * (alpha < 7))
    # ... but where only one Mach number reaches the ramp, a function of alpha is all the data show
    high = np.clip(alpha - 7.0, 0.0, None) * (mach == 0.3)
    assert left_beyond(high * mach, alpha) < 0.01 * np.ptp(high * mach)
    gear = np.concatenate([np.repeat([0.0, 1.0], len(a) // 2) for _, a in logs])  # up, then down, in each log
    assert left_beyond(0.01 * gear * mach, gear) > 0.5 * 0.01 * (0.5 - 0.3)
    assert left_beyond(0.01 * gear, gear) < 1e-9


def test_a_cause_held_out_conditions_predict_worse_is_listed_after_those_they_confirm_or_cannot_test():
    """Seed 8,200,248 of the detection curve: a stock-737 drag table in the elevator, x6.25 on held-out
    conditions, was listed after a smooth(mach) term 184 times its floor that made them worse (x0.94;
    each condition trims at its own elevator). Confirmed first, then untestable, then predicted worse."""
    from diagnose.verdict import rank

    worse = {"holdout_gain": 0.94, "size_over_floor": 183.9}
    confirmed = {"holdout_gain": 6.25, "size_over_floor": 156.5}
    untested = {"holdout_gain": float("nan"), "size_over_floor": 20.0}
    small = {"holdout_gain": 1.3, "size_over_floor": 4.0}
    order = sorted([worse, untested, small, confirmed], key=rank)
    assert order == [confirmed, small, untested, worse]


def test_of_the_discrepancies_ten_times_their_floor_the_one_that_explains_most_of_its_residual_comes_first():
    """Fresh 8,500,066: a stock-737 drag dead band in the elevator, 16.7 times its floor, taking 96 % of the
    drag residual, came after a smooth(mach) 28 times its floor that took 28 %; 8,700,256: a lift table
    in the gear, 19.4 times and 96 %, after a lift in qhat 48.7 times and 42 % (what a vane delay left).
    Beyond ten times the floor the share of the residual orders them; below it, the size over the
    floor, after every one beyond it."""
    from diagnose.verdict import rank

    mach = {"holdout_gain": 1.06, "size_over_floor": 28.0, "explains_pct": 27.9}
    elevator = {"holdout_gain": 4.28, "size_over_floor": 16.7, "explains_pct": 95.6}
    smaller = {"holdout_gain": 1.5, "size_over_floor": 9.0, "explains_pct": 99.0}
    smallest = {"holdout_gain": 1.5, "size_over_floor": 4.0, "explains_pct": 99.5}
    no_share = {"holdout_gain": 1.5, "size_over_floor": 12.0, "explains_pct": float("nan")}
    assert sorted([smallest, smaller, no_share, mach, elevator], key=rank) == [
        elevator,
        mach,
        no_share,
        smaller,
        smallest,
    ]


def _row(seed, size, hit, named, effect="dCD = +0.001 * step(mach; at 0.5)", shape=0.1):
    """A case record as ``benchmarks/detection_curve.py`` writes it (its CSV's columns)."""
    return {
        "seed": seed,
        "aircraft": "A320",
        "conditions": "3 ft/s",
        "effect": effect,
        "size_over_floor": size,
        "hit": hit,
        "hit_as_flown": hit,
        "named": named,
        "invented": "",
        "rejected_strong": "",
        "false_positive": False,
        "shape_error": shape if hit else np.nan,
        "discrepancy": bool(named),
    }


def test_the_detection_table_counts_hits_per_size_and_a_cause_named_on_an_effect_out_of_reach_as_false(
    tmp_path, monkeypatch, capsys
):
    """The benchmark's table, and its merge of two runs: an effect the data hold less than 0.3 of the
    floor of is as good as a null, and another cause named there is counted (seed 8,250,020, a
    seed: an A320 with a +0.21 deg vane bias in 3 ft/s, "CD vs flap, gear" and "CL vs mach,
    alpha" named beside an elevator step the manoeuvres never reached)."""
    import sys

    import pandas as pd

    from benchmarks.detection_curve import main, table

    a = [
        _row(1, 0.1, False, "CD vs alpha_deg, mach"),
        _row(2, 0.2, False, ""),
        _row(3, 5.0, True, "CD vs mach"),
        _row(4, 12.0, True, "CD vs mach", shape=0.3),
        _row(5, 40.0, False, "CL vs alpha_deg"),
    ]
    b = [_row(6, 15.0, True, "CD vs mach", shape=0.1), _row(7, np.nan, False, "", effect="")]
    text = table(a + b)
    assert "| 3-10 | 1 | 1 | 100 % |" in text and "| 10 and more | 3 | 2 | 67 % | 2 (67 %) | 0.20, 0.28 |" in text
    assert (
        "2 effects, 0 named, 1 with another aerodynamic cause named" in text and "Nulls: 1, false positives: 0" in text
    )
    for name, rows in (("a", a), ("b", b)):
        (tmp_path / name).mkdir()
        pd.DataFrame(rows).to_csv(tmp_path / name / "detection_curve.csv", index=False)
    merge = ["detection_curve.py", "--merge", str(tmp_path / "a"), str(tmp_path / "b"), "--out"]
    monkeypatch.setattr(sys, "argv", merge + [str(tmp_path / "ab")])
    assert main() == 0
    assert (tmp_path / "ab" / "detection_curve.md").read_text().strip() == text  # the CSV read back: the same table
    assert (tmp_path / "ab" / "detection_curve.png").stat().st_size > 10_000
    before = (tmp_path / "a" / "detection_curve.csv").read_bytes()
    capsys.readouterr()
    monkeypatch.setattr(sys, "argv", merge + [str(tmp_path / "a")])
    with pytest.raises(SystemExit) as stop:
        main()
    err = capsys.readouterr().err.strip().splitlines()
    assert stop.value.code == 2 and "--out" in err[-1] and "one of the folders merged" in err[-1]
    assert (tmp_path / "a" / "detection_curve.csv").read_bytes() == before
    (tmp_path / "empty").mkdir()
    monkeypatch.setattr(
        sys, "argv", merge[:2] + [str(tmp_path / "a"), str(tmp_path / "empty"), "--out", str(tmp_path / "new")]
    )
    with pytest.raises(SystemExit) as stop:
        main()
    err = capsys.readouterr().err.strip().splitlines()
    assert stop.value.code == 2 and "no detection_curve.csv there" in err[-1] and not (tmp_path / "new").exists()


def test_the_a320_benchmark_matrix_crosses_its_alpha_gap_at_one_mach_number(tmp_path):
    """The A320's Mach 0.5 trims at 10,000 ft about 3 deg of alpha below its Mach 0.4; the benchmark's
    sixth condition, Mach 0.5 at the dynamic pressure of Mach 0.4 at 10,000 ft, trims within
    0.3 deg of Mach 0.4's alpha on the A320 itself, so that an effect changing in that gap changes within
    one Mach number too."""
    import jsbsim

    from benchmarks.detection_curve import A320, same_alpha_alt_ft
    from campaign.diagnosis.run import load_data
    from campaign.validation.support import run_matrix

    alt = same_alpha_alt_ft(10000, 0.4, 0.5)
    assert f"alt_ft = {alt}" in A320 and 20000 < alt < 22000
    points = [("up", 0, 0.4, 10000), ("up", 0, 0.5, alt), ("up", 0, 0.5, 10000)]
    data = run_matrix(
        tmp_path, matrix_toml(points, "gap"), str(Path(jsbsim.get_default_root_dir()) / "aircraft" / "A320")
    )
    trim = {lg.condition[:2]: float(np.median(lg.data["alpha_deg"].to_numpy()[:20])) for lg in load_data(data)}
    assert abs(trim[(alt, 0.5)] - trim[(10000.0, 0.4)]) < 0.3, trim
    assert trim[(10000.0, 0.4)] - trim[(10000.0, 0.5)] > 2.0, trim


def test_a_cause_beside_one_that_fell_is_judged_on_the_fit_without_it():
    """The report fits each coefficient with its named causes' terms only, so a cause is judged on that
    fit: the terms of a cause that fell where another cause of its coefficient stands are dropped and the
    rest judged again (an A320 null's "CD vs alpha_deg", 15 times its floor beside a collinear "CD vs CL,
    flap_deg" that fell, spanned 0.0076 where the CD residual spans 0.0014; seed 9,402,865). A
    coefficient where nothing stands keeps its fit; an unconfirmed discrepancy stands; a split one of whose
    parts was dropped is read whole, as one whose part fell."""
    from diagnose.causes import Cause
    from diagnose.diagnosis import _dropped, _split_stands
    from diagnose.terms import Term

    a, cl, g, m = (
        Term("linear", (v,), centers=(0.0,), ranges=((-np.inf, np.inf),))
        for v in ("alpha_deg", "CL", "gear_norm", "mach")
    )

    def cause(coefficient, term, **verdict):
        return Cause(
            coefficient,
            list(term.variables),
            [term],
            "linear",
            {},
            0.0,
            verdict={"accepted": False, "unconfirmed": False, **verdict},
        )

    stands, fell = cause("CD", a, accepted=True), cause("CD", cl)
    alone, open_ = cause("Cm", g), cause("CL", m, unconfirmed=True)
    beside_open = cause("CL", cl)
    dropped, gone = _dropped([stands, fell, alone, open_, beside_open], {})
    assert dropped == {"CD": frozenset({cl}), "CL": frozenset({cl})}
    assert {id(c) for c in gone} == {id(fell), id(beside_open)}
    assert _dropped([stands, open_], dropped) == (dropped, [])  # judged again, nothing more fell: settled
    assert not _split_stands([stands], "CD", [a, cl], dropped)
    assert _split_stands([stands], "CD", [a, cl], {})
    assert _split_stands([stands], "CD", [a, g], dropped)  # the dropped term is not of this split


def test_an_a320_vane_bias_in_turbulence_is_that_bias_not_a_drag_in_alpha(tmp_path):
    """The benchmark's A320 null 9,402,865 (its matrix, 3 ft/s, a +0.230 deg alpha-vane bias): the
    kinematics split the bias into +0.056 +- 0.064 deg and a 3.0 % scale and corrected neither; the
    stepwise search took the drag the bias leaves as "CD vs alpha_deg" beside a collinear "CD vs CL,
    flap_deg", the two 0.0076 and 0.0066 in size where the residual spans 0.0014. The second fell on
    held-out data, the first was named on its share of the pair. Judged on the fit without it, the drag in
    alpha is the bias's, with the lift's: the residuals refine the bias, and nothing aerodynamic is named."""
    from campaign.validation.support import pairs

    a320 = Path(__import__("jsbsim").get_default_root_dir()) / "aircraft" / "A320"
    matrix = matrix_toml(
        pairs((0, 0.3, 5000), (0, 0.4, 10000), (0, 0.5, 10000), (15, 0.3, 5000), (0, 0.4, 19500.0), (0, 0.5, 21000.0)),
        "a320",
    )
    doc = diagnose_overlay(
        tmp_path,
        None,
        a320,
        matrix,
        seed=9_402_865,
        sigma_fps=3.0,
        channels="[channels.alpha_deg]\nbias = 0.2299727280418436\n",
    )
    assert not discrepancies(doc), [(c["coefficient"], c["variables"]) for c in discrepancies(doc)]
    first = doc["causes"][0]
    assert (first["kind"], first["channel"], first["error"]) == ("sensor", "alpha_deg", "bias")
    assert abs(first["estimate"] - 0.230) <= 2 * first["se"], (first["estimate"], first["se"])
