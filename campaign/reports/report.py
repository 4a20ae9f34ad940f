"""``campaign report DIR``: one self-contained HTML file for a campaign folder or a diagnosis folder.

Reads only what the other commands wrote (``manifest.json``, ``identification/``,
``replays/``; or ``diagnosis.json`` and its plots) and writes ``DIR/report.html``. Each replay
case gets a page in the form FAA 14 CFR Part 60 Appendix A asks of a test: name and objective,
initial conditions, what was driven or constrained, tolerances, the source of the validation
data, and the result, dated and labelled, over-plotted on the reference with the tolerance
bands about the reference (never shifted to the simulator's start).
"""

from __future__ import annotations

import datetime as dt
import json
import re
from html import escape
from pathlib import Path

import pandas as pd

from campaign.reports import html
from campaign.errors import UserError
from campaign.reports.diagnosis import diagnosis_report
from campaign.replays.report import TOL_ALT_FT, TOL_TAS_KT, TOL_THETA_DEG
from infra.provenance import tool_text

#: The replayed models a campaign report sums up, in this order.
REPLAYED = ("linear", "nonlinear")
#: The sign-off block's roles.
SIGN_OFF = ("Prepared", "Checked", "Approved")
POINT_ID = re.compile(r"h(?P<alt>\d+)_m(?P<mach>[\d.]+)_f(?P<flap>\d+)_g(?P<gear>up|dn)")
REPORT = "report.html"


def _coverage_figure(man: dict) -> str:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9.0, 4.2))
    ax = fig.subplots()
    flaps: dict = {}
    failed = []
    for p in man["points"]:
        m = POINT_ID.fullmatch(p["id"])
        if not m:
            continue
        alt, mach, flap, gear = float(m["alt"]), float(m["mach"]), int(m["flap"]), m["gear"]
        x = mach + (0.006 if gear == "dn" else -0.006)
        if p["status"] != "ok":
            failed.append((x, alt))
            continue
        flaps.setdefault(flap, []).append((x, alt, gear))
    for i, (flap, pts) in enumerate(sorted(flaps.items())):
        for gear, marker in (("up", "o"), ("dn", "s")):
            xs = [(x + 0.003 * i, a) for x, a, g in pts if g == gear]
            if xs:
                ax.scatter(
                    *zip(*xs),
                    marker=marker,
                    color=f"C{i}",
                    s=26,
                    label=f"flap {flap}, gear {'down' if gear == 'dn' else 'up'}",
                )
    if failed:
        ax.scatter(*zip(*failed), marker="x", color="red", s=60, label="failed")
    ax.set_xlabel("Mach")
    ax.set_ylabel("altitude [ft]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return html.svg(fig, "Status points flown (circles gear up, squares gear down) and failed (red crosses).")


def _holds(man: dict) -> str:
    rows = [
        (
            p["id"],
            man_,
            v.get("alpha_deg_max_dev", float("nan")),
            v.get("mach_max_dev", float("nan")),
            v.get("alt_ft_max_dev", float("nan")),
        )
        for p in man["points"]
        for man_, v in p.get("excursions", {}).items()
    ]
    if not rows:
        return "<p>No held manoeuvre in this campaign.</p>"
    worst = [max(r[i] for r in rows) for i in (2, 3, 4)]
    return (
        f"<p>The altitude/speed hold during {len(rows)} gear transitions: largest excursion from the trimmed "
        f"state alpha {worst[0]:.3g} deg, Mach {worst[1]:.3g}, altitude {worst[2]:.3g} ft.</p>"
        + html.table(
            ["point", "manoeuvre", "alpha max dev [deg]", "Mach max dev", "altitude max dev [ft]"], rows, left=2
        )
    )


def _identification(folder: Path) -> str:
    ident = folder / "identification"
    path = ident / "identification.json"
    if not path.exists():
        return "<p>Not identified (run <code>campaign identify</code>).</p>"
    doc = json.loads(path.read_text())
    keys = [
        ("CL", "dalpha_rad", "CLalpha"),
        ("CL", "delevator_rad", "CLde"),
        ("Cm", "dalpha_rad", "Cmalpha"),
        ("Cm", "qhat_rad", "Cmq"),
        ("Cm", "delevator_rad", "Cmde"),
        ("CD", "const", "CD0"),
    ]
    rows = []
    for point, p in doc["points"].items():
        cells = [escape(point), escape(str(p["gear"]))]
        for c, r, _ in keys:
            se = p[c].get("se_coloured", p[c]["bse"]).get(r)
            v = p[c]["params"].get(r)
            cells.append("n/i" if v is None else f"{v:.4g} &plusmn; {se:.2g}")
        cells.append(f"{min(p[c]['rsquared'] for c in ('CL', 'CD', 'Cm')):.4f}")
        cells.append(escape(p.get("method", doc.get("method", "ee"))))
        rows.append(cells)
    names = {"ee": "equation error", "oe": "output error", "fe": "filter error"}
    method = doc.get("method", "ee")
    failed = doc.get("not_converged", [])
    body = [
        f"<p>Eq. (3) by <b>{names[method]}</b>; estimates with standard errors corrected for coloured "
        "residuals; n/i: not identifiable; each point's method is the one its numbers came from.</p>"
    ]
    if failed:
        body.append(
            f"<p><b>Not converged by {names[method]}</b> (equation-error estimates kept, labelled ee): "
            + "; ".join(f"{escape(d['point'])}: {escape(d['reason'])}" for d in failed)
            + "</p>"
        )
    body.append(html.table(["point", "gear", *[k[2] for k in keys], "min R^2", "method"], rows, left=2, raw=True))
    lin = [
        (
            k,
            m["alpha_trim_deg"],
            *(m["increment"][c] for c in ("CL", "CD", "Cm")),
            *(m["C0_gearDn_bse"][c] for c in ("CL", "CD", "Cm")),
        )
        for k, m in doc["linear"].items()
    ]
    if lin:
        body += [
            "<h3>Linear gear model (eq. 4): gear-down minus gear-up C0</h3>",
            html.table(["condition", "alpha trim [deg]", "dCL", "dCD", "dCm", "se CL", "se CD", "se Cm"], lin),
        ]
    if doc.get("notes"):
        body.append("<ul>" + "".join(f"<li>{escape(n)}</li>" for n in doc["notes"]) + "</ul>")
    for png in sorted((ident / "plots").glob("*.png")):
        body.append(html.png(png, png.stem, png.stem.replace("_", " ")))
    return "".join(body)


def part60_results(folder: Path) -> list[dict]:
    """Each replay case, loop and identified model of a campaign folder with its Part 60 result, as the
    report's summary shows them (``replays/metrics.csv``; empty without replays).

    Returns
    -------
    list of dict
        ``case``, ``loop``, ``model``, ``result`` (``"PASS"`` or ``"FAIL"``), ``smallest_margin_pct``
        (the smallest of the airspeed, altitude and pitch margins, each as a share of its tolerance
        [%]; negative outside it) and ``limited_by`` (the channel of that margin).
    """
    f = Path(folder) / "replays" / "metrics.csv"
    if not f.exists():
        return []
    rows = []
    for r in pd.read_csv(f).sort_values(["case", "loop"], kind="stable").itertuples():
        if r.model == "reference":
            continue
        tol_theta = float(getattr(r, "tol_theta_deg", TOL_THETA_DEG))
        margins = {
            "airspeed": (TOL_TAS_KT - r.max_err_tas_kt) / TOL_TAS_KT,
            "altitude": (TOL_ALT_FT - r.max_err_alt_ft) / TOL_ALT_FT,
            "pitch": (tol_theta - r.max_err_theta_deg) / tol_theta,
        }
        limit = min(margins, key=margins.get)
        rows.append(
            {
                "case": r.case,
                "loop": r.loop,
                "model": r.model,
                "result": "PASS" if r.qtg_pass else "FAIL",
                "smallest_margin_pct": round(100.0 * margins[limit], 1),
                "limited_by": limit,
            }
        )
    return rows


def _verdict(result: str) -> str:
    return f'<span class="{result.lower()}">{result}</span>'


def _summary(folder: Path, man: dict, results: list[dict]) -> tuple[str, str]:
    """The first page: Part 60 results per case and loop, the test identifiers and the sign-off block;
    and the navigation's list of cases with their results."""
    models = [m for m in REPLAYED if any(r["model"] == m for r in results)]
    by_case: dict = {}
    for r in results:
        by_case.setdefault((r["case"], r["loop"]), {})[r["model"]] = r
    if results:
        counts = "; ".join(
            f"the {m} gear model passes {sum(r['result'] == 'PASS' for r in results if r['model'] == m)} "
            f"of {sum(r['model'] == m for r in results)}"
            for m in models
        )
        head = (
            f"<p>FAA 14 CFR Part 60, Appendix A, test 2.c.4 (gear change dynamics), {len(by_case)} case and loop "
            f"pairs: {escape(counts)}. Margin: the smallest of the airspeed, altitude and pitch margins, each as "
            "a share of its tolerance (negative: outside it).</p>"
        )
        rows = []
        for (case, loop), got in by_case.items():
            cells = [f'<a href="#{html.anchor(f"case-{case}-{loop}")}">{escape(case)}</a>', escape(loop)]
            for m in models:
                r = got.get(m)
                cells += (
                    [_verdict(r["result"]), f"{r['smallest_margin_pct']:.0f} % ({r['limited_by']})"]
                    if r
                    else ["not flown", ""]
                )
            rows.append(cells)
        table = html.table(
            ["case", "loop", *[h for m in models for h in (f"{m} model", f"{m}: smallest margin")]],
            rows,
            left=2,
            raw=True,
        )
    else:
        head, table = (
            (
                "<p>No Part 60 results: no replays in this campaign (<code>campaign replay</code> flies "
                "them once the gear models are identified).</p>"
            ),
            "",
        )
    s = man.get("settings", {})
    logs = sorted(folder.glob("*.parquet"))
    flown = dt.datetime.fromtimestamp((folder / "manifest.json").stat().st_mtime, dt.timezone.utc)
    tool = man.get("tool") or {}
    ids = [
        ("campaign", man.get("campaign", folder.name)),
        (
            "matrix",
            f"{Path(s['matrix']).name if s.get('matrix') else 'default'} (sha256 {s.get('matrix_sha256', '')[:16]})",
        ),
        ("aircraft", f"{Path(s.get('aircraft', '')).name} (sha256 {s.get('aircraft_sha256', '')[:16]})"),
        (
            "effects",
            f"{Path(s['effects']).name} (sha256 {s.get('effects_sha256', '')[:16]})"
            if s.get("effects")
            else "none (the bare model)",
        ),
        ("instruments", f"{s.get('instruments')} (sha256 {s.get('instruments_sha256', '')[:16]})"),
        ("seed", s.get("seed")),
        ("flight logs", f"{len(logs)} (sha256 {html.sha256_files(logs)[:16] if logs else ''})"),
        ("flown by", f"{tool.get('name', '')} {tool.get('version', 'unknown')}".strip()),
        ("report written by", tool_text()),
        ("campaign written", flown.strftime("%Y-%m-%d %H:%M UTC")),
        ("report written", html.now()),
    ]
    sign = html.table(["", "name", "signature", "date"], [(r, "", "", "") for r in SIGN_OFF], left=4)
    body = (
        head
        + table
        + "<h3>Test identifiers</h3>"
        + html.definitions(ids)
        + '<p class="note">Hashes: the first 16 hex digits of each SHA-256; the traceability section gives them '
        "whole.</p><h3>Sign-off</h3>" + sign.replace("<table>", '<table class="signoff">', 1)
    )
    nav = (
        " ".join(
            f'<a href="#{html.anchor(f"case-{case}-{loop}")}">{escape(case)} ({escape(loop)}) '
            + " ".join(f"<small>{m}</small> {_verdict(got[m]['result'])}" for m in models if m in got)
            + "</a>"
            for (case, loop), got in by_case.items()
        )
        + " "
    )
    return body, nav


def _replay_pages(folder: Path) -> list[tuple[str, str, str]]:
    rep = folder / "replays"
    if not (rep / "metrics.csv").exists():
        return [html.section("replays", "Replays", "<p>No replays (run <code>campaign replay</code>).</p>")]
    metrics = pd.read_csv(rep / "metrics.csv")
    if "pass_probability" in metrics:  # only bands drawn from the identification on disk
        from campaign.replays.report import load_bands

        valid = load_bands(folder)[0]
        keys = metrics.case + "__" + metrics.model + "__" + metrics.loop
        metrics.loc[~keys.isin(valid), "pass_probability"] = float("nan")
    cases = (
        {c["name"]: c for c in json.loads((rep / "cases.json").read_text())} if (rep / "cases.json").exists() else {}
    )
    stamp = dt.datetime.fromtimestamp((rep / "metrics.csv").stat().st_mtime, dt.timezone.utc).strftime(
        "%Y-%m-%d %H:%M UTC"
    )
    pages = []
    for (case, loop), rows in metrics.groupby(["case", "loop"], sort=True):
        c = cases.get(case, {})
        action = "extension" if c.get("gear") == "extend" else "retraction"
        objective = (
            f"Part 60 Appendix A, 2.c.4 (gear change dynamics): the aeroplane's response to landing-gear "
            f"{action}, {'controls free (open loop)' if loop == 'open' else 'altitude and speed held (closed loop)'}."
        )
        initial = [
            ("pressure altitude [ft]", c.get("alt_ft")),
            ("indicated airspeed [kt]", c.get("ias_kt")),
            ("flap [deg]", c.get("flap_deg")),
            ("weight [lb]", c.get("weight_lb")),
            ("trimmed flight before the command [s]", c.get("pre_s")),
            ("after the travel [s]", c.get("post_s")),
        ]
        driven = (
            "Gear command stepped at the end of the trimmed segment; elevator, stabilizer and throttle frozen at trim."
            if loop == "open"
            else "Gear command stepped; the autopilot's altitude and speed hold drives elevator and throttle."
        )
        result_rows = []
        for _, r in rows.iterrows():
            if r["model"] == "reference":
                continue
            tol_theta = float(r.get("tol_theta_deg", TOL_THETA_DEG))
            margins = (
                TOL_TAS_KT - r["max_err_tas_kt"],
                TOL_ALT_FT - r["max_err_alt_ft"],
                tol_theta - r["max_err_theta_deg"],
            )
            ok = bool(r["qtg_pass"])
            prob = r.get("pass_probability", float("nan"))
            result_rows.append(
                (
                    r["model"],
                    r["max_err_tas_kt"],
                    r["max_err_alt_ft"],
                    r["max_err_theta_deg"],
                    tol_theta,
                    f"{min(margins[0] / TOL_TAS_KT, margins[1] / TOL_ALT_FT, margins[2] / tol_theta) * 100:.0f} %",
                    f'<span class="{"pass" if ok else "fail"}">{"PASS" if ok else "FAIL"}</span>',
                    "not drawn" if pd.isna(prob) else f"{prob * 100:.0f} % of {int(r['band_draws'])} draws",
                )
            )
        body = [
            f"<p><b>Objective.</b> {escape(objective)}</p>",
            "<h3>Initial conditions</h3>",
            html.definitions((k, v) for k, v in initial if v is not None),
            f"<h3>Driven or constrained</h3><p>{escape(driven)}</p>",
            "<h3>Tolerances</h3><p>Airspeed &plusmn;3 kt, altitude &plusmn;100 ft, pitch &plusmn;1.5 deg or 20 % of "
            "the reference's pitch change (the larger), about the reference time history.</p>",
            "<h3>Validation data</h3><p>The reference aircraft (the model with the effects the campaign was flown "
            "with) flying the same case: <code>"
            + escape(f"replays/{case}__reference__{loop}.parquet")
            + "</code>.</p>",
            f"<h3>Result ({stamp})</h3>",
            html.table(
                [
                    "model",
                    "max err airspeed [kt]",
                    "max err altitude [ft]",
                    "max err pitch [deg]",
                    "pitch tolerance [deg]",
                    "smallest margin",
                    "result",
                    "pass probability",
                ],
                [
                    (m, html.fmt(a), html.fmt(b), html.fmt(t), html.fmt(tt), mg, res, escape(pp))
                    for m, a, b, t, tt, mg, res, pp in result_rows
                ],
                raw=True,
            ),
            "<p>Pass probability: the share of the identified model's Monte Carlo draws from its covariance "
            "(<code>campaign replay --bands N</code>) that stay within the tolerances; the plots shade their "
            "95 % bands.</p>",
        ]
        plot = rep / "plots" / f"{case}__{loop}.png"
        if plot.exists():
            body.append(
                html.png(
                    plot,
                    f"{case} {loop}",
                    f"{case}, {loop} loop: identified models over the reference, "
                    "errors with the tolerance bands about the reference.",
                )
            )
        pages.append(
            html.section(html.anchor(f"case-{case}-{loop}"), f"{case} ({loop} loop)", "".join(body), page=True)
        )
    return pages


def campaign_report(folder: Path) -> str:
    man = json.loads((folder / "manifest.json").read_text())
    ok = sum(p["status"] == "ok" for p in man["points"])
    failed = [(p["id"], p["reason"]) for p in man["points"] if p["status"] != "ok"]
    coverage = _coverage_figure(man) + (
        html.table(["point", "why it failed"], failed, left=2) if failed else "<p>Every point flew.</p>"
    )
    summary, cases_nav = _summary(folder, man, part60_results(folder))
    sections = [
        html.section("summary", "Summary", summary),
        html.section(
            "coverage",
            "Matrix coverage",
            f"<p>{ok} of {len(man['points'])} status points flown"
            f"{'' if man.get('complete') else ' (campaign incomplete)'}.</p>" + coverage,
        ),
        html.section("holds", "Trim and hold quality", _holds(man)),
        html.section("identification", "Identification", _identification(folder), page=True),
        *_replay_pages(folder),
        html.section(
            "trace",
            "Traceability",
            html.traceability(
                folder,
                man,
                {
                    "identification": folder / "identification" / "identification.json",
                    "replay metrics": folder / "replays" / "metrics.csv",
                },
            ),
            page=True,
        ),
    ]
    return html.document(
        f"Campaign {man.get('campaign', folder.name)}",
        f"{folder.resolve()} · instruments {man.get('settings', {}).get('instruments')} · {html.now()}",
        sections,
        nav_extra=f'<div class="cases">Part 60: {cases_nav}</div>' if cases_nav else "",
        nav_skip=[a for a, _, _ in sections if a.startswith("case-")] if cases_nav else (),
    )


def write_report(folder: Path) -> Path:
    """Write ``folder/report.html`` for a campaign folder or a diagnosis folder; return its path."""
    folder = Path(folder)
    if (folder / "diagnosis.json").exists():
        text = diagnosis_report(folder)
    elif (folder / "manifest.json").exists():
        text = campaign_report(folder)
    else:
        raise UserError(f"{folder}: neither a campaign folder (manifest.json) nor a diagnosis (diagnosis.json)")
    return html.write(folder / REPORT, text)
