"""The documentation's tables and figures, made from the benchmark results in ``benchmarks/results/``.

    python benchmarks/tables.py            # write docs/generated/*.md, *.png and README.md's table
    python benchmarks/tables.py --check    # exit 1 if README.md's table is not what the results give

Every figure the documentation quotes comes from a file in ``benchmarks/results/`` (CSV or JSON), each
holding the command that measured it and the commit and date of the code it measured; nothing here
measures anything. ``mkdocs build`` runs :func:`write_docs` first (``docs/hooks.py``), so the site always shows
the results as they are on disk; the README's validation table is written between two marker lines and
checked by the tests (``tests/test_product_text.py``).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
GENERATED = ROOT / "docs" / "generated"
README = ROOT / "README.md"
BEGIN = "<!-- validation table: written by benchmarks/tables.py from benchmarks/results/, do not edit -->"
END = "<!-- end of validation table -->"
BEGIN_METHODS = "<!-- methods table: written by benchmarks/tables.py from benchmarks/results/, do not edit -->"
END_METHODS = "<!-- end of methods table -->"
BANDS = ("0.3-1", "1-3", "3-10", "10 and more")


def _json(name: str) -> dict:
    return json.loads((RESULTS / name).read_text())


def _csv(name: str) -> list[dict]:
    with open(RESULTS / name, newline="") as f:
        return list(csv.DictReader(f))


def _pct(k: int, n: int) -> str:
    return f"{k} of {n} ({100 * k / n:.1f} %)" if n else "-"


def _table(head: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _source(doc: dict) -> str:
    """The provenance line under a table: the command, the commit and its date."""
    commit = doc.get("code_commit") or doc.get("recorded_at_commit")
    what = "code at commit" if "code_commit" in doc else "recorded at commit"
    return (
        f"\n*Measured by `{doc['command']}`; {what} `{commit[:7]}` ({doc['date'][:10]}). "
        f"Data: `benchmarks/results/`.*\n"
    )


def current_ranges() -> list[dict]:
    """The detection-curve ranges flown at the decisions of the newest range measured."""
    ranges = _csv("detection_curve_ranges.csv")
    newest = max(ranges, key=lambda r: r["code_date"])
    return [r for r in ranges if r["decisions_of"] == newest["decisions_of"]]


def detection_headline() -> dict:
    """Hits from 3 and from 10 times the floor and false positives over the current ranges."""
    cur = current_ranges()
    s = {
        k: sum(int(r[k]) for r in cur)
        for k in ("effects", "nulls", "false_positives", "effects_3_10", "hits_3_10", "effects_10_up", "hits_10_up")
    }
    s["ranges"] = cur
    return s


def validation_table() -> str:
    """The README's one table: what the tool has been validated on."""
    d = detection_headline()
    seeds = ", ".join(
        f"{int(r['seed_first']):,}-{int(r['seed_first']) + int(r['effects']) + int(r['nulls']) - 1:,}"
        for r in d["ranges"]
    )
    ident = _json("identification_accuracy.json")
    ee = next(r for r in ident["rows"] if r["method"] == "equation error" and r["data"].startswith("flight-test"))
    est = _json("estimators_flight_data.json")
    attas = [r for r in est["rows"] if r["check"].startswith("ATTAS")]
    hfb = [r for r in est["rows"] if r["check"].startswith("HFB")]
    worst = lambda rows: max(abs(r["ours"] / r["published"] - 1) for r in rows) * 100  # noqa: E731
    hit = _json("diagnosis_hit_rate.json")
    sensor = next(c for c in hit["cases"] if c["case"].startswith("sensor faults"))
    gain = _json("replay_gain.json")
    share = [c["gain"] / c["truth_gain"] for c in gain["cases"] if c["extended"]]
    big = [c for c in gain["cases"] if c["extended"] and c["size_over_floor"] >= 10]
    big_within = sum(bool(c["within_floor_plus_10pct"]) for c in big)
    big_worst = max(c["worst_extended_over_floor"] for c in big) if big else float("nan")
    rows = [
        [
            "Hidden effects the diagnosis was not built against, 10 times the noise floor or more: first cause right",
            f"{d['effects']} random effects in our 737, the stock 737 and A320 (seeds {seeds})",
            _pct(d["hits_10_up"], d["effects_10_up"]),
            "`benchmarks/detection_curve.py`",
        ],
        [
            "... 3 to 10 times the noise floor",
            "the same",
            _pct(d["hits_3_10"], d["effects_3_10"]),
            "`benchmarks/detection_curve.py`",
        ],
        [
            "Null flights (no effect) that name a cause",
            f"{d['nulls']} nulls, the same aircraft",
            f"{d['false_positives']} of {d['nulls']}",
            "`benchmarks/detection_curve.py`",
        ],
        [
            "Sensor faults named first, nothing aerodynamic invented",
            "our 737, 5 fault kinds x 4 seeds",
            f"{sensor['count']} of {sensor['of']}",
            "`benchmarks/diagnosis_hit_rate.py`",
        ],
        [
            "Replay gain of the extension over the gain of the true model (1: the best any extension can do)",
            f"{len(share)} hidden-effect cases",
            f"{min(share):.2f} to {max(share):.2f}",
            "`benchmarks/replay_gain.py`",
        ],
        [
            "After the extension, held-out replays where the cause acts within their floor plus 10 % "
            "(worst error over the floor of a perfect model)",
            f"the {len(big)} of those at 10 times the noise floor or more",
            f"{big_within} of {len(big)} (worst x{big_worst:.2f})",
            "`benchmarks/replay_gain.py`",
        ],
        [
            "Derivatives by equation error in turbulence, RMS error against the XML",
            "97 2-3-1-1s, paper matrix",
            f"CLalpha {ee['CLalpha']} %, Cmalpha {ee['Cmalpha']} %, Cmq {ee['Cmq']} %",
            "`benchmarks/identification_accuracy.py --methods`",
        ],
        [
            "Output error on real flight data (ATTAS), against the published estimates",
            "2 elevator records",
            f"within {worst(attas):.3f} %",
            "`tests/test_estimators.py`",
        ],
        [
            "Filter error on real flight data in turbulence (HFB-320)",
            "1 record",
            f"within {worst(hfb):.1f} % (4 main derivatives)",
            "`tests/test_estimators.py`",
        ],
    ]
    if (RESULTS / "real_terms.json").exists():
        rows += _real_terms_rows(_json("real_terms.json"))
    if (RESULTS / "real_replays.json").exists():
        rows.append(_real_replays_row(_json("real_replays.json")))
    if (RESULTS / "bad_input_sweep.json").exists():
        bad = _json("bad_input_sweep.json")
        rows.append(
            [
                "Bad input refused in one line naming the file and field, exit code 2, nothing on disk changed",
                f"{bad['inputs_tried']:,} generated bad matrices, maps, data files, instrument profiles, "
                f"overlays and command lines",
                f"{bad['clean']:,} of {bad['inputs_tried']:,}, {bad['tracebacks']} tracebacks",
                "`benchmarks/bad_input_sweep.py`",
            ]
        )
    if (RESULTS / "replay_floor.json").exists():
        doc = _json("replay_floor.json")
        rows.append(_replay_floor_row(doc))
        if all("per_log" in r for r in doc["rows"]):
            rows.append(_floor_cover_row(doc))
    return _table(["what", "on", "result", "measured by"], rows)


def _real_terms_rows(doc: dict) -> list[list[str]]:
    """The rows of ``benchmarks/real_terms.py``: terms taken out of models identified on real records."""
    rows = doc["rows"]
    smaller = [r for r in rows if r.get("change") and "right" not in r and "first_aero" in r]
    named = sum(bool(r["first_aero"]) and r["first_aero"][0] == r["change"][0] for r in smaller)
    other = sum(bool(r["first_aero"]) and r["first_aero"][0] != r["change"][0] for r in smaller)
    lo, hi = doc["named_gains"]
    null = [r for r in rows if r.get("change") is None]
    return [
        [
            "A term taken out of a model identified on a real record: named first, and the other record confirms it",
            "the ATTAS's 2 elevator records and the HFB-320 record's 3-2-1-1 and pulse, each identified on its own "
            f"and diagnosed with the other held out, {doc['named_cases'] // len(doc['records'])} terms",
            f"{doc['named_right']} of {doc['named_cases']} (held-out gain x{lo:.2f} to x{hi:.2f})",
            "`benchmarks/real_terms.py`",
        ],
        [
            "... smaller changes (pitch stiffness x0.8, quadratic terms, constant offsets): named in their coefficient",
            "the same",
            f"{named} of {len(smaller)}, {other} in another coefficient, no aerodynamic cause for the rest",
            "`benchmarks/real_terms.py`",
        ],
        [
            "... the models as identified: aerodynamic causes named",
            "the same",
            f"{sum(bool(r['first_aero']) for r in null)} of {len(null)}",
            "`benchmarks/real_terms.py`",
        ],
    ]


def _real_replays_row(doc: dict) -> list[str]:
    """The row of ``benchmarks/real_replays.py``: real records flown on the other record's model."""
    tol, n = doc["tolerance"], doc["within_tolerance"]

    def pitch(kind: str) -> str:
        worst = [r[kind]["max_error"]["theta_deg"] for r in doc["rows"]]
        return f"{min(worst):.2f} to {max(worst):.2f} deg"

    return [
        f"A real record flown on a model identified from the other record of its aeroplane: within Part 60 over "
        f"the record ({tol['theta_deg']:g} deg pitch, {tol['alt_ft']:g} ft), trimmed as the record starts "
        "(trimmed steady)",
        "the ATTAS's 2 elevator records, the HFB-320's 3-2-1-1 and pulse",
        f"{n['as_started']} of {n['of']} ({n['steady']} of {n['of']}); worst pitch {pitch('as_started')} "
        f"({pitch('steady')})",
        "`benchmarks/real_replays.py`",
    ]


def _replay_floor_row(doc: dict) -> list[str]:
    """A perfect model against its own turbulent data: worst over the Part 60 windows and the whole logs."""
    half, full = doc["tolerances"]["window (half Part 60)"], doc["tolerances"]["log (Part 60)"]
    runs = doc["rows"]

    def within(row: dict, key: str, tol: dict) -> bool:
        return all(row["worst"][key][ch] <= tol[ch] for ch in tol)

    worst = {ch: max(r["worst"]["window"][ch] for r in runs) for ch in half}
    sigmas = sorted({r["sigma_fps"] for r in runs})
    seeds = sorted({r["seed"] for r in runs})
    return [
        "A perfect model replaying its own turbulent data: held-out logs within half the Part 60 gear-change "
        "tolerances over their windows (0.75 deg, 1.5 kt, 50 ft), and within the tolerances over the whole log",
        f"our 737, paper matrix, {' and '.join(f'{s:g}' for s in sigmas)} ft/s, {len(seeds)} seeds each",
        f"{sum(within(r, 'window', half) for r in runs)} of {len(runs)} runs within half "
        f"(worst {worst['theta_deg']:.2f} deg, {worst['tas_kt']:.2f} kt, {worst['alt_ft']:.0f} ft); "
        f"{sum(within(r, 'log', full) for r in runs)} of {len(runs)} within the tolerances",
        "`benchmarks/replay_floor.py`",
    ]


def _floor_cover_row(doc: dict) -> list[str]:
    """A perfect model's own replay errors within the floor: the share of logs x channels x spans."""
    from campaign.diagnosis.floor import COVER_CALIBRATION_SEEDS

    def covered(rows: list) -> list[bool]:
        return [
            e <= f
            for r in rows
            for spans in r["per_log"].values()
            for span in spans.values()
            for e, f in span.values()
            if e == e and f == f
        ]

    fresh = [r for r in doc["rows"] if r["seed"] not in COVER_CALIBRATION_SEEDS]
    every, unseen = covered(doc["rows"]), covered(fresh)
    logs = sum(len(r["per_log"]) for r in doc["rows"])
    seeds = sorted({r["seed"] for r in fresh})
    return [
        "A perfect model's own held-out replay errors within the floor the diagnosis gives beside them",
        f"the same runs: {logs} held-out logs, 5 channels, judged windows and whole logs",
        f"{100 * sum(every) / len(every):.1f} % of {len(every)}"
        + (
            f"; {100 * sum(unseen) / len(unseen):.1f} % of the {len(unseen)} of seeds {seeds[0]}-{seeds[-1]}, "
            "which the floor's factor was not calibrated on"
            if unseen
            else ""
        ),
        "`benchmarks/replay_floor.py`",
    ]


def detection_page() -> str:
    """docs/generated/detection.md: the detection curve's tables."""
    d = detection_headline()
    bands = _csv("detection_curve_bands.csv")
    cur = {r["seed_first"] for r in d["ranges"]}
    out = ["The ranges flown at the present decisions, together:\n\n"]
    rows = []
    for b in BANDS:
        sel = [r for r in bands if r["seed_first"] in cur and r["band"] == b]
        e, h = sum(int(r["effects"]) for r in sel), sum(int(r["hits"]) for r in sel)
        rows.append(
            [
                b,
                e,
                h,
                f"{100 * h / e:.0f} %" if e else "-",
                sum(int(r["invented"]) for r in sel),
                sum(int(r["strong_rejected"]) for r in sel),
            ]
        )
    out.append(
        _table(["size / floor", "effects", "hits", "hit rate", "invented causes", "strong candidates rejected"], rows)
    )
    out.append(f"\nFalse positives: {d['false_positives']} of {d['nulls']} null flights.\n")
    first = d["ranges"][-1]
    out.append(
        f"\n*Measured by `{first['command']}` (and the same for each range); code at commits "
        + ", ".join(f"`{r['code_commit'][:7]}` ({r['code_date'][:10]})" for r in d["ranges"])
        + ". Data: `benchmarks/results/detection_curve_bands.csv`.*\n"
    )
    out.append("\n### Every range, at the code it was flown with\n\n")
    rows = [
        [
            f"{int(r['seed_first']):,}",
            f"{r['effects']}, {r['nulls']}",
            r["conditions_per_case"],
            r["shapes_drawn_on"],
            _pct(int(r["hits_3_10"]), int(r["effects_3_10"])),
            _pct(int(r["hits_10_up"]), int(r["effects_10_up"])),
            r["false_positives"],
            f"`{r['code_commit'][:7]}` ({r['code_date'][:10]})",
        ]
        for r in _csv("detection_curve_ranges.csv")
    ]
    out.append(
        _table(
            [
                "first seed",
                "effects, nulls",
                "conditions per case",
                "shapes drawn on",
                "3-10 x floor",
                "10 x floor and more",
                "false positives",
                "code",
            ],
            rows,
        )
    )
    out.append("\n*Data: `benchmarks/results/detection_curve_ranges.csv` (with the command of each range).*\n")
    return "".join(out)


def detection_figure(path: Path) -> None:
    """Hit rate per size band: each range in grey, the present decisions' ranges together in black."""
    from matplotlib.figure import Figure

    bands = _csv("detection_curve_bands.csv")
    cur = {r["seed_first"] for r in current_ranges()}
    fig = Figure(figsize=(6.4, 3.6), dpi=110)
    ax = fig.add_subplot()
    x = range(len(BANDS))
    for seed in dict.fromkeys(r["seed_first"] for r in bands):
        sel = {r["band"]: r for r in bands if r["seed_first"] == seed}
        ax.plot(x, [100 * int(sel[b]["hits"]) / int(sel[b]["effects"]) for b in BANDS], color="0.8", lw=1)
    tot = [
        (
            sum(int(r["hits"]) for r in bands if r["seed_first"] in cur and r["band"] == b),
            sum(int(r["effects"]) for r in bands if r["seed_first"] in cur and r["band"] == b),
        )
        for b in BANDS
    ]
    ax.plot(x, [100 * h / e for h, e in tot], "o-", color="k", lw=2, label="present decisions")
    ax.plot([], [], color="0.8", lw=1, label="each range at its code")
    ax.set_xticks(list(x), [f"{b} x" for b in BANDS])
    ax.set_xlabel("size of the hidden effect / noise floor")
    ax.set_ylabel("first cause right [%]")
    ax.set_ylim(0, 102)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", frameon=False)
    fig.subplots_adjust(left=0.11, right=0.98, top=0.96, bottom=0.16)
    fig.savefig(path)


def methods_page() -> str:
    doc = _json("identification_accuracy.json")
    cols = ("CLalpha", "CLde", "Cmalpha", "Cmq", "Cmde")

    def cell(r, c):
        if c not in r:
            return "-"
        return f"{r[c]} ({r[c + '_points']} points)" if c + "_points" in r else r[c]

    rows = [
        [r["data"], r["method"], r.get("converged", "-"), *[cell(r, c) for c in cols], r["s_per_point"]]
        for r in doc["rows"]
    ]
    out = _table(["data", "method", "converged", *cols, "s / point"], rows) + _source(doc)
    out += f"\n{doc['setup']}. {doc['caveat'][0].upper() + doc['caveat'][1:]}.\n"
    out += (
        "\nShare of estimates within 3 coloured standard errors of the XML, flight-test profile: "
        + ", ".join(f"{k} {v}" for k, v in doc["within_3_coloured_se"].items())
        + ".\n"
    )
    return out


SYMBOL = {
    "Z_alpha_per_s": "Z_alpha",
    "Z_q": "Z_q",
    "Z_de_per_s": "Z_de",
    "M_alpha_per_s2": "M_alpha",
    "M_q_per_s": "M_q",
    "M_de_per_s2": "M_de",
}


def _cli_result(r: dict) -> str:
    """What one command-line run gave, against its reference where it has one."""
    d = r["derivatives"]
    values = ", ".join(f"{SYMBOL.get(k, k)} {v['ours']:.4g}" for k, v in d.items() if v["ours"] is not None)
    ref = next((k for k in ("published_fe", "independent_oe", "published_oe") if k in next(iter(d.values()))), None)
    if r["method"] == "oe" and r["record"] == "HFB-320":
        ref = "independent_oe"
    if ref is None or r["method"] == "ee" and ref != "published_fe":
        return values if r["record"] != "ATTAS" else f"{values} (nothing published in these terms)"
    worst = max(abs(v["ours"] / v[ref] - 1) for v in d.values() if v["ours"] is not None) * 100
    against = {
        "published_fe": "the published filter-error estimates",
        "independent_oe": "an output-error run of the data set's own model",
        "published_oe": "the published output-error estimates",
    }[ref]
    return f"{values}: within {worst:.2g} % of {against}"


def methods_table() -> str:
    """The README's methods table: each estimator on the real records through the command line."""
    doc = _json("estimators_cli.json")
    rows = []
    for r in doc["rows"]:
        ok = "yes" if r["exit_code"] == 0 and not r["not_converged"] else f"{r['not_converged']} of {r['points']} not"
        ok = ok if r["method"] != "ee" else "-"
        rows.append([r["record"], f"`{r['command']}`", ok, _cli_result(r)])
    return _table(["record", "command", "converged", "gives"], rows) + _source(doc)


def estimators_page() -> str:
    doc = _json("estimators_flight_data.json")
    rows = [
        [r["check"], r["parameter"], r["published"], r["ours"], f"{100 * (r['ours'] / r['published'] - 1):+.3g} %"]
        for r in doc["rows"]
    ]
    return (
        _table(["record, method", "parameter", "published", "ours", "difference"], rows)
        + _source(doc)
        + "".join(f"\n- {n}." for n in doc["notes"])
        + "\n"
    )


def hit_rate_page() -> str:
    doc = _json("diagnosis_hit_rate.json")
    out = _table(["case", "result", ""], [[c["case"], f"{c['count']} of {c['of']}", c["detail"]] for c in doc["cases"]])
    out += _source(doc) + f"\n{doc['setup'][0].upper() + doc['setup'][1:]}.\n"
    fl = doc["detection_floors"]
    out += f"\nDetection floors ({fl['setup']}): " + ", ".join(f"{s['error']} {s['floor']}" for s in fl["sensor"])
    out += (
        "; hidden aerodynamic effects down to "
        + ", ".join(f"{a['floor']} ({a['family']})" for a in fl["aero_times_drawn_size"])
        + " times their drawn size.\n"
    )
    return out


def replay_gain_page() -> str:
    doc = _json("replay_gain.json")
    rows = [
        [
            c["effect"],
            f"{c['size_over_floor']:.3g}",
            c["moved_most"],
            f"x{c['gain']:.3g}",
            f"x{c['truth_gain']:.3g}",
            c["logs_where_acts"],
            f"x{c['worst_extended_over_floor']:.2f}",
            {True: "yes", False: "no", None: "-"}[c["within_floor_plus_10pct"]],
        ]
        for c in doc["cases"]
    ]
    return (
        _table(
            [
                "hidden effect",
                "size / floor",
                "moved most",
                "gain",
                "the truth's gain",
                "logs where it acts",
                "worst extended / floor",
                "within floor + 10 %",
            ],
            rows,
        )
        + _source(doc)
        + f"\n{doc['setup'][0].upper() + doc['setup'][1:]}.\n"
    )


def multisine_page() -> str:
    doc = _json("multisine_information.json")
    rows = [
        [r["derivative"], f"{r['predicted'][0]}-{r['predicted'][1]}", f"{r['realized'][0]}-{r['realized'][1]}"]
        for r in doc["rows"]
    ]
    return (
        _table(["derivative", "predicted", "realized"], rows)
        + _source(doc)
        + f"\n{doc['setup'][0].upper() + doc['setup'][1:]}.\n"
    )


def plan_page() -> str:
    p, t = _json("plan_separation.json"), _json("turn_airspeed.json")
    r = p["results"]
    out = _table(
        ["", ""],
        [
            ["cases", r["cases"]],
            ["an open rival before the plan", r["open_rival_before"]],
            [
                "the rival's separation before [standard errors]",
                f"{r['rival_separation_before_se'][0]} to {r['rival_separation_before_se'][1]}",
            ],
            ["the plan", r["plan"]],
            ["right cause first after", f"{r['right_cause_first_after']} of {r['open_rival_before']}"],
            ["rival settled after (5 standard errors)", f"{r['settled_after']} of {r['open_rival_before']}"],
            ["separation after [standard errors]", f"{r['separation_after_se'][0]} to {r['separation_after_se'][1]}"],
            ["planned separation [standard errors]", f"{r['planned_se'][0]} to {r['planned_se'][1]}"],
            [
                "measured / planned",
                f"{r['measured_over_planned'][0]} to {r['measured_over_planned'][1]} "
                f"(mean {r['measured_over_planned_mean']})",
            ],
        ],
    )
    out += _source(p) + f"\n{p['setup'][0].upper() + p['setup'][1:]}.\n"
    tr = t["results"]
    out += (
        f"\n**Airspeed error from a level turn.** {t['setup'][0].upper() + t['setup'][1:]}. With no error hidden "
        f"({tr['null_seeds']} seeds) the error came out between {tr['null_error_kt'][0]} and +{tr['null_error_kt'][1]} kt, "
        f"at {tr['null_z'][0]} to +{tr['null_z'][1]} standard errors (RMS {tr['null_z_rms']}: the standard error is "
        f"about that much too small); with a 3 % scale hidden it came out {tr['scale_3pct_error_from_truth_kt'][0]} to "
        f"{tr['scale_3pct_error_from_truth_kt'][1]} kt from the truth.\n" + _source(t)
    )
    return out


SPEED = RESULTS / "speed"
#: The stages speed_table.py times with 1 and 2 jobs, in the order of the table.
STAGES = (
    "fly (138 manoeuvres)",
    "identify",
    "replay",
    "plots (redrawn)",
    "run: fly through plots",
    "diagnose (full matrix)",
)
#: The diagnoses speed_table.py times with 2 jobs, each the median of its runs.
DIAGNOSES = ("diagnose, no plots", "diagnose, key plots", "diagnose x3 (291 points), no plots")


def speed_results() -> list[dict]:
    """Every result of ``benchmarks/speed_table.py`` (``benchmarks/results/speed/*.json``), in the order
    they were measured."""
    docs = [{**json.loads(p.read_text()), "file": p.name} for p in SPEED.glob("*.json")]
    return sorted(docs, key=lambda d: (d["date"], d["file"]))


def _speed_source(docs: list[dict]) -> str:
    """The provenance line under a speed table: each result's command, commit, date and machine."""

    def one(d: dict) -> str:
        m = d.get("machine", {})
        where = f", {m['cpu']}, {m['cores']} cores" if "cpu" in m else ""
        return f"`{d['command']}`, code at commit `{d['code_commit'][:7]}`, measured {d['date'][:10]}{where}"

    return "\n*Measured by " + "; and by ".join(one(d) for d in docs) + ". Data: `benchmarks/results/speed/`.*\n"


def _num(v, fmt: str = ".1f") -> str:
    return "-" if v is None else format(v, fmt)


def speed_page() -> str:
    docs = speed_results()
    out = []
    st = next((d for d in reversed(docs) if f"{STAGES[0]}, 1 job" in d["figures"]), None)
    if st is not None:
        rows = []
        for name in STAGES:
            one, two = st["figures"].get(f"{name}, 1 job", {}), st["figures"].get(f"{name}, 2 jobs", {})
            rows.append(
                [
                    name,
                    _num(one.get("wall_s")),
                    _num(two.get("wall_s")),
                    f"x{one['wall_s'] / two['wall_s']:.2f}" if one and two else "-",
                    _num(two.get("cpu_s")),
                    _num(two.get("main_mb"), ".0f"),
                    _num(two.get("worker_mb"), ".0f"),
                    _num(two.get("unique_mb"), ".0f"),
                    _num(two.get("sum_mb"), ".0f"),
                ]
            )
        out.append(
            _table(
                [
                    "stage (paper matrix, flight-test profile)",
                    "1 job [s]",
                    "2 jobs [s]",
                    "speed-up",
                    "CPU, 2 jobs [s]",
                    "main peak [MB]",
                    "worker peak [MB]",
                    "worker USS [MB]",
                    "main + workers peak [MB]",
                ],
                rows,
            )
            + _speed_source([st])
        )
        ratio = st["figures"].get("flying loop / raw fdm.run()", {}).get("ratio")
        if ratio is not None:
            out.append(f"\nThe flying loop steps at {ratio:.2f} of raw `fdm.run()` (`benchmarks/stepping.py`).\n")
    diag = [d for d in docs if DIAGNOSES[0] in d["figures"]][-2:]
    if diag:
        head = ["the diagnosis, 2 jobs (median of the runs)"]
        for d in diag:
            head += [f"`{d['code_commit'][:7]}` wall [s]", "CPU [s]", "main + workers peak [MB]", "PSS [MB]"]
        rows = [
            [name]
            + [
                x
                for d in diag
                for x in (
                    _num(d["figures"].get(name, {}).get("wall_s")),
                    _num(d["figures"].get(name, {}).get("cpu_s")),
                    _num(d["figures"].get(name, {}).get("sum_mb"), ".0f"),
                    _num(d["figures"].get(name, {}).get("pss_mb"), ".0f"),
                )
            ]
            for name in DIAGNOSES
        ]
        busy = [d["figures"][DIAGNOSES[0]].get("others_busy") for d in diag]
        out.append(
            "\n"
            + _table(head, rows)
            + "\nOther work on the machine took "
            + " and ".join(f"{100 * b:.0f} %" for b in busy if b is not None)
            + " of its cores meanwhile (the CPU-seconds are the diagnosis's own: its processes'). The peak "
            "is each process's high-water mark summed over the main process and its workers: each counts "
            "the 200 MB a process holds once it has imported numpy, scipy, pandas and JSBSim, most of it "
            "shared with the others; PSS counts a shared page once over the processes.\n"
        )
        staged = [d for d in diag if d.get("stages")]
        if staged:
            names = list(staged[-1]["stages"]["stages"])
            rows = [
                [n]
                + [
                    x
                    for d in staged
                    for x in (
                        _num(d["stages"]["stages"].get(n, {}).get("wall_s"), ".2f"),
                        _num(d["stages"]["stages"].get(n, {}).get("cpu_s"), ".2f"),
                    )
                ]
                for n in names
            ]
            head = ["stage of the diagnosis (paper matrix, 2 jobs, key plots)"]
            for d in staged:
                head += [f"`{d['code_commit'][:7]}` wall [s]", "CPU [s]"]
            out.append("\n" + _table(head, rows))
        out.append(_speed_source(diag))
    scaled = next((d for d in reversed(docs) if any(k.startswith("x10 ") for k in d["figures"])), None)
    if scaled is not None:
        seeds = sorted({k.split(" seed ")[1].split(":")[0] for k in scaled["figures"] if k.startswith("x10 ")})
        fly_ref = scaled["figures"].get(f"{STAGES[0]}, 2 jobs", {}).get("wall_s")
        rows = []
        for sd in seeds:
            of = {
                k.split(": ")[1]: v
                for k, v in scaled["figures"].items()
                if k.startswith("x10 ") and k.split(": ")[0].endswith(f"seed {sd}")
            }
            fly, ident = of["fly, 2 jobs"], of["identify, 2 jobs"]
            rows.append([sd, _num(fly["wall_s"]), _num(ident["wall_s"]), f"{fly['wall_s'] / 970 * 1000:.0f}"])
        out.append(
            "\n**Ten times the points** (each paper point at 10 altitudes 150 ft apart, 970 points, 2 jobs, "
            "one run per noise seed"
            + (f"; the paper matrix flies {fly_ref / 97 * 1000:.0f} ms a point" if fly_ref else "")
            + "):\n\n"
            + _table(["seed", "fly [s]", "identify [s]", "fly per point [ms]"], rows)
            + _speed_source([scaled])
        )
    c = _json("scale_identify.json")
    r = c["results"]
    peak = r["identify_main_peak_mb"]
    out.append(
        f"\n**A hundred times the points** ({c['setup']}): flying {r['fly_s']} s ({r['fly_per_point_ms']} ms "
        f"a point; {r['points_flown']:,} flew, {r['points_failed']} failed: {r['failed_because']}); "
        f"identification {r['identify_s']} s, main process peak {peak[0]}-{peak[1]} MB.\n" + _source(c)
    )
    rs = _json("report_speed.json")
    out.append(
        "\n**The HTML report**: "
        + "; ".join(f"{r['folder']}: {r['size_mb']} MB written in {r['write_s']} s" for r in rs["rows"])
        + ".\n"
        + _source(rs)
    )
    return "".join(out)


PAGES = {
    "validation-summary.md": validation_table,
    "detection.md": detection_page,
    "methods.md": methods_page,
    "estimators-cli.md": methods_table,
    "estimators.md": estimators_page,
    "hit-rate.md": hit_rate_page,
    "replay-gain.md": replay_gain_page,
    "multisine.md": multisine_page,
    "plan.md": plan_page,
    "speed.md": speed_page,
}


def readme_with_table(text: str) -> str:
    """README.md's text with the validation and methods tables between their markers replaced by the results'."""
    for begin, end, make in ((BEGIN, END, validation_table), (BEGIN_METHODS, END_METHODS, methods_table)):
        head, sep, rest = text.partition(begin)
        if not sep or end not in rest:
            raise SystemExit(f"{README}: the marker lines of {begin[5:-4]!r} are missing")
        text = head + begin + "\n" + make() + rest[rest.index(end) :]
    return text


def write_docs() -> None:
    """docs/generated/: every page of :data:`PAGES` and the detection figure (written only when changed)."""
    GENERATED.mkdir(parents=True, exist_ok=True)
    for name, make in PAGES.items():
        path = GENERATED / name
        text = make()
        if not path.exists() or path.read_text() != text:
            path.write_text(text)
    detection_figure(GENERATED / "detection.png")


def write() -> None:
    """docs/generated/ and README.md's validation table."""
    write_docs()
    text = README.read_text()
    new = readme_with_table(text)
    if new != text:
        README.write_text(new)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only check that README.md's table is up to date")
    args = ap.parse_args(argv)
    if args.check:
        text = README.read_text()
        if readme_with_table(text) != text:
            print(
                f"{README}: the validation table differs from benchmarks/results/ (run python benchmarks/tables.py)",
                file=sys.stderr,
            )
            return 1
        return 0
    write()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
