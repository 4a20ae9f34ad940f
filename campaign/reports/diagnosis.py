"""The diagnosis half of ``campaign report``: verdict, causes with their evidence, the plots, the
before-and-after replays, the data compatibility, the rejected candidates and the extension."""

from __future__ import annotations

import json
from html import escape
from pathlib import Path

from campaign.reports import html
from diagnose.config import recorded
from diagnose.held_out import told_text


def label(c: dict) -> str:
    """A cause's name: ``CD vs mach`` for an aerodynamic one, ``ax_fps2 bias (in CD)`` for a sensor's."""
    if c.get("variables"):
        return f"{c['coefficient']} vs {' x '.join(c['variables'])}"
    return f"{c.get('channel', '?')} {c.get('error', c.get('shape', ''))} (in {c.get('coefficient', '?')})"


def _cause_rows(causes: list[dict]) -> list[tuple]:
    rows = []
    for i, c in enumerate(causes, 1):
        ev, v = c.get("evidence", {}), c.get("verdict", {})
        alts = (
            ", ".join(f"{a['channel']} {a['error']} {a['needs']:+.3g}" for a in ev.get("sensor_alternatives", []))
            or "none"
        )
        rows.append(
            (
                f"{i}. {label(c)}",
                c.get("kind", ""),
                c.get("shape", ""),
                c.get("size", float("nan")),
                ev.get("F", float("nan")),
                v.get("noise_floor", float("nan")),
                v.get("size_over_floor", float("nan")),
                v.get("instrument_errors_make", float("nan")),
                v.get("holdout_gain", float("nan")),
                alts,
            )
        )
    return rows


def _gain(g: dict) -> str:
    rows = [(c, v["before"], v["after"], f"x{v['gain']:.2f}") for c, v in g["residual_rms"].items()]
    rep = [(ch, v["before"], v["after"], f"x{v['gain']:.2f}") for ch, v in g["replay_max_error"].items()]
    moved = g.get("replay_moved", {})
    acts = [
        (
            ch + (" (moved most)" if ch == g.get("replay_moved_most") else ""),
            v["before"],
            v["after"],
            f"x{v['gain']:.2f}",
            moved.get(ch, float("nan")),
        )
        for ch, v in g.get("replay_where_acts", {}).items()
    ]
    return (
        f"<p>First aerodynamic cause: <b>{escape(g['cause'])}</b>; it acts in {len(g['cause_exercised_in'])} of "
        f"{len(g['held_out_logs'])} held-out manoeuvres.</p>"
        + html.table(["coefficient", "residual RMS before", "after", "gain"], rows)
        + html.table(["replay channel", "max error before", "after", "gain"], rep)
        + "<p>Where the cause acts (<code>trim_</code>: the trimmed start's controls, the model's trim against "
        "the measured one; moved: how far the extension moves the replay, in Part 60 tolerances):</p>"
        + html.table(["replay channel", "max error before", "after", "gain", "moved [tolerances]"], acts)
    )


def diagnosis_report(folder: Path) -> str:
    doc = json.loads((folder / "diagnosis.json").read_text())
    causes = doc["causes"]
    verdict = doc["verdict"]
    if causes:
        verdict += f": {label(causes[0])} ({causes[0].get('shape', '')})"
    elif doc.get("largest_rejected"):
        lr = doc["largest_rejected"]
        verdict += f" (largest candidate: {lr['candidate']}: {lr['reason']})"
    header = [
        "cause",
        "kind",
        "shape",
        "size",
        "F",
        "noise floor",
        "size / floor",
        "instrument errors make",
        "held-out gain",
        "sensor alternatives",
    ]
    together = doc.get("flown_together")
    caution = f'<p class="note">Caution: {escape(together["text"])}.</p>' if together else ""
    caution += "".join(f'<p class="note">Caution: {escape(t)}.</p>' for t in told_text(doc.get("held_out_check") or {}))
    sections = [
        html.section(
            "verdict",
            "Verdict",
            f'<p class="verdict">{escape(verdict)}</p>'
            + caution
            + html.definitions(
                [
                    ("data", doc["data"]["path"]),
                    ("logs", doc["data"]["logs"]),
                    ("held out", len(doc["data"]["held_out"])),
                    ("model", doc["model"]),
                ]
            ),
        )
    ]
    body = html.table(header, _cause_rows(causes)) if causes else "<p>No cause named.</p>"
    if doc.get("unconfirmed"):
        body += "<h3>Discrepancies these data cannot confirm</h3>" + html.table(header, _cause_rows(doc["unconfirmed"]))
    overview = folder / "plots" / "residuals_vs_cause.png"
    if overview.exists():
        body += html.png(overview, "residuals against each cause", "Residuals against each cause's variables.")
    sections.append(html.section("causes", "Causes and evidence", body))
    if doc.get("rivals"):
        settled_se = recorded(doc).settled_se
        rows = [
            (
                r["cause"],
                r["rival"],
                r["kind"],
                r["separation_se"],
                r["predicted_se"],
                "settled" if r["separation_se"] >= settled_se else "not settled: campaign plan",
                ", ".join(f"{k} {v:.3g}" for k, v in r.get("by_coefficient", {}).items() if v > 0),
            )
            for r in doc["rivals"]
        ]
        sections.append(
            html.section(
                "rivals",
                "Rival explanations",
                html.table(
                    ["cause", "rival", "kind", "separation [se]", "expected [se]", "", "likelihood ratio from"],
                    rows,
                    left=3,
                )
                + "<p>The separation is the likelihood ratio of the cause's fit and the rival's, over CL, CD and Cm "
                f"and the data compatibility's estimate, in standard errors; at {settled_se:g} or more these data "
                "reject the rival. <code>campaign plan</code> designs the flights that would settle the others.</p>",
            )
        )
    if doc.get("gain"):
        body = _gain(doc["gain"])
        for png in sorted((folder / "plots").glob("response_*.png")):
            body += html.png(
                png,
                png.stem,
                f"Held-out manoeuvre {png.stem[len('response_') :]}: replays on the model "
                "and on the extended model against the data.",
            )
        if doc.get("bands"):
            body += "<h3>Monte Carlo bands of the extended model</h3>" + html.table(
                [
                    "held-out log",
                    "draws",
                    "Part 60 pass probability",
                    "held-back draw inside the band",
                    "widest band, theta [deg]",
                    "widest band, altitude [ft]",
                ],
                [
                    (
                        k,
                        v["draws"],
                        v["pass_probability"],
                        f"{100 * v['held_back_draw_inside']:.0f} %",
                        v["width_max"]["theta_deg"],
                        v["width_max"]["alt_ft"],
                    )
                    for k, v in doc["bands"].items()
                ],
            )
        r = doc.get("refine")
        if r and r.get("error"):
            body += f'<p class="note">Refinement by output error failed: {escape(r["error"])}</p>'
        elif r:
            body += (
                f"<h3>Refined by output error ({r['iterations']} iterations)</h3>"
                + html.table(
                    ["term", "scale", "se", "se coloured"],
                    [(k, v, r["se"][k], r["se_coloured"][k]) for k, v in r["scales"].items()],
                )
                + (f'<p class="note">{escape(r["caveat"])}</p>' if r.get("caveat") else "")
                + _gain(r["gain"])
            )
        sections.append(html.section("gain", "Before and after, held-out data", body, page=True))
    if doc.get("replays"):
        sections.append(html.section("replays", "Held-out replays and their floor", _replays(doc)))
    compat = doc.get("data_compatibility")
    if compat:
        rows = [
            (
                p["channel"],
                p["error"],
                p["estimate"] if p["identifiable"] else "n/i",
                p["se"] if p["identifiable"] else "",
                p["z"] if p["identifiable"] else "",
                p["applied"],
                p["reason"] or "",
            )
            for p in compat["parameters"]
        ]
        sections.append(
            html.section(
                "compat",
                "Data compatibility",
                html.table(["channel", "error", "estimate", "se", "z", "applied", "why not / note"], rows, left=2)
                + f"<p>Vertical gust in the reconstruction: {compat.get('vertical_gust_rms_fps', float('nan')):.2g} ft/s RMS.</p>",
            )
        )
    rejected = [(label(c), c.get("kind", ""), c.get("verdict", {}).get("reason", "")) for c in doc["rejected"]]
    sections.append(
        html.section(
            "rejected",
            "Rejected candidates",
            html.table(["candidate", "kind", "why"], rejected, left=3) if rejected else "<p>None.</p>",
        )
    )
    xml = Path(doc["extension_xml"]) if doc.get("extension_xml") else None
    if xml is not None and xml.exists():
        sections.append(
            html.section(
                "extension",
                "Extension (JSBSim XML)",
                f"<p>Merged into <code>{escape(str(doc['extension']))}</code>.</p><details><summary>"
                f"{escape(xml.name)}</summary><pre>{escape(xml.read_text())}</pre></details>",
            )
        )
    paths = [Path(p) for p in doc["data"].get("paths", [doc["data"]["path"]])]
    manifests = {
        ("data manifest" if len(paths) == 1 else f"data manifest {i}"): p / "manifest.json"
        for i, p in enumerate(paths, 1)
    }
    sections.append(
        html.section(
            "trace",
            "Traceability",
            html.traceability(
                folder,
                None,
                {"diagnosis": folder / "diagnosis.json", **manifests, "extension": folder / "extension.xml"},
            ),
        )
    )
    return html.document("Diagnosis", f"{doc['data']['path']} against {doc['model']}", sections)


def _replays(doc: dict) -> str:
    """Each held-out replay's error over its judged window (and the whole log) beside the floor a perfect
    model leaves there, and the Part 60 verdict on the model."""
    rows = []
    windows = doc.get("replay_windows", {})
    for name, r in doc["replays"].items():
        w = windows.get(name, {})
        for ch in ("theta_deg", "tas_kt", "alt_ft", "alpha_deg", "q_dps"):
            c = r.get(ch, {})
            win = c.get("window") or {}
            rows.append(
                (
                    name,
                    ch,
                    f"{w.get('from_s', float('nan')):.1f}-{w.get('to_s', float('nan')):.1f} s",
                    win.get("model", float("nan")),
                    c.get("model", float("nan")),
                    win.get("floor", float("nan")),
                    c.get("floor", float("nan")),
                    win.get("tolerance", float("nan")),
                    (win.get("part60") or {}).get("says", ""),
                )
            )
    why = {k: v["why"] for k, v in doc.get("replay_starts", {}).items() if v.get("why")}
    body = html.table(
        [
            "held-out log",
            "channel",
            "window",
            "error, window",
            "error, log",
            "floor, window",
            "floor, log",
            "Part 60 tolerance",
            "verdict (model)",
        ],
        rows,
        left=3,
    )
    body += "".join(f'<p class="note">{escape(k)}: not flown: {escape(str(v))}</p>' for k, v in why.items())
    floor = doc.get("replay_floor", {}).get("method", "")
    return (
        body
        + (f"<p>Floor: {escape(floor)}.</p>" if floor else "")
        + (
            "<p>Gear transitions are judged over the Part 60 window (5 s before to 15 s after the gear starts to move), "
            "the others over the manoeuvre; replays and data are compared low-passed at 2 Hz.</p>"
        )
    )
