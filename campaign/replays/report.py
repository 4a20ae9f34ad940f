"""Replay metrics and plots from stored replay logs (no JSBSim here).

Tolerances: FAA 14 CFR Part 60, Appendix A, Table A2A, test 2.c.4 (gear change
dynamics): +-3 kt airspeed, +-100 ft altitude, and +-1.5 deg or 20 % of the pitch
change, whichever is less restrictive (we read "20 %" as 20 % of the reference's
largest pitch-angle change during the test).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pandas as pd

from campaign.errors import UserError
from campaign.orchestration.store import atomic_write, clean_temporaries, read_log
from identify.figures import emptied_axes, new_figure
from infra.pool import pmap
from infra.provenance import tool_text

CHANNELS = (
    ("theta_deg", "pitch angle [deg]"),
    ("alpha_deg", "angle of attack [deg]"),
    ("q_dps", "pitch rate [deg/s]"),
    ("tas_kt", "true airspeed [kt]"),
    ("alt_ft", "altitude [ft]"),
)
TOL_TAS_KT = 3.0
TOL_ALT_FT = 100.0
TOL_THETA_DEG = 1.5
FIGSIZE = (13, 12)  # [in]
COLORS = {"reference": "k", "linear": "tab:red", "nonlinear": "tab:blue"}


def theta_tolerance(ref: pd.DataFrame) -> float:
    """Pitch tolerance: 1.5 deg or 20 % of the reference's pitch change, the larger [deg]."""
    return max(TOL_THETA_DEG, 0.2 * float(np.max(np.abs(ref.theta_deg - ref.theta_deg.iloc[0]))))


def load_replays(results: Path, names: list[str] | None = None) -> dict[tuple[str, str, str], pd.DataFrame]:
    """Stored replay logs: ``{(case, model, loop): log}``, cases filtered by partial names."""
    folder = Path(results) / "replays"
    files = sorted(folder.glob("*__*__*.parquet"))
    if not files:
        raise UserError(f"{folder}: no replay logs; run 'campaign replay {results}' first")
    out = {}
    for f in files:
        case, model, loop = f.stem.split("__")
        if names and not any(n in case for n in names):
            continue
        out[(case, model, loop)] = read_log(f)[0]
    if not out:
        raise UserError(f"--case: no stored replay matches {', '.join(names or [])}")
    return out


def metrics(replays: dict, bands: dict | None = None) -> pd.DataFrame:
    """Max and RMS errors against the reference, and the Part 60 verdict.

    With ``bands`` (:func:`load_bands`'s summary), each model's
    ``pass_probability`` (the share of its Monte Carlo draws within the tolerances) and
    ``band_draws``; otherwise empty.
    """
    bands = bands or {}
    rows = []
    for (case, model, loop), log in sorted(replays.items()):
        ref = replays.get((case, "reference", loop))
        if model == "reference" or ref is None:
            continue
        n = min(len(ref), len(log))
        err = log.iloc[:n].reset_index(drop=True) - ref.iloc[:n].reset_index(drop=True)
        row = {"case": case, "model": model, "loop": loop}
        for ch, _ in CHANNELS:
            row[f"max_err_{ch}"] = float(np.max(np.abs(err[ch])))
            row[f"rms_err_{ch}"] = float(np.sqrt(np.mean(err[ch] ** 2)))
        tol_theta = theta_tolerance(ref.iloc[:n])
        row["tol_theta_deg"] = tol_theta
        row["qtg_pass"] = bool(
            row["max_err_tas_kt"] <= TOL_TAS_KT
            and row["max_err_alt_ft"] <= TOL_ALT_FT
            and row["max_err_theta_deg"] <= tol_theta
        )
        b = bands.get(f"{case}__{model}__{loop}", {})
        row["pass_probability"] = b.get("pass_probability", np.nan)
        row["band_draws"] = b.get("draws", np.nan)
        rows.append(row)
    df = pd.DataFrame(rows)
    first = [
        "case",
        "model",
        "loop",
        "max_err_theta_deg",
        "rms_err_theta_deg",
        "max_err_alpha_deg",
        "max_err_q_dps",
        "max_err_tas_kt",
        "max_err_alt_ft",
        "qtg_pass",
        "pass_probability",
    ]
    return df[first + [c for c in df.columns if c not in first]]


def metrics_text(df: pd.DataFrame) -> str:
    cols = [
        "case",
        "model",
        "loop",
        "max_err_theta_deg",
        "rms_err_theta_deg",
        "max_err_alpha_deg",
        "max_err_q_dps",
        "max_err_tas_kt",
        "max_err_alt_ft",
        "tol_theta_deg",
        "qtg_pass",
    ]
    head = (
        "Replay errors against the reference aircraft (max |model - reference|).\n"
        "Part 60 gear change (2.c.4): airspeed 3 kt, altitude 100 ft, pitch 1.5 deg or 20 % of its change.\n\n"
    )
    if df["pass_probability"].notna().any():
        cols.append("pass_probability")
        head += (
            "pass_probability: the share of the identified model's Monte Carlo draws (from its covariance, "
            "campaign replay --bands) within the tolerances.\n\n"
        )
    table = df[cols].copy()
    table["qtg_pass"] = table["qtg_pass"].map({True: "pass", False: "FAIL"})
    text = head + table.to_string(index=False, float_format=lambda v: f"{v:#.3g}") + "\n"
    failing = table[table.qtg_pass == "FAIL"]
    if len(failing):
        text += (
            "\nOutside the Part 60 tolerances: "
            + "; ".join(f"{r.case} {r.model} {r.loop}" for r in failing.itertuples())
            + "\n"
        )
    return text


def _case_axes(fig) -> np.ndarray:
    """The grid of :func:`plot_case` on ``fig``: one row per channel, history and error."""
    axes = fig.subplots(len(CHANNELS), 2, sharex=True)
    fig.subplots_adjust(left=0.07, right=0.98, top=0.95, bottom=0.05, hspace=0.12, wspace=0.22)
    return axes


def plot_case(replays: dict, case: str, loop: str, axes=None, bands: dict | None = None):
    """Time histories and residuals of one case and loop (paper Figs. 13-16).

    Left: reference, linear and nonlinear models. Right: model minus reference,
    with the Part 60 tolerance bands where they apply. ``bands`` (``{(case, model, loop):
    frame of t_s, <channel>_lo, <channel>_hi}``) shades each model's 95 % Monte Carlo band.
    """
    bands = bands or {}
    ref = replays[(case, "reference", loop)]
    if axes is None:
        axes = _case_axes(new_figure(FIGSIZE))
    fig = axes[0][0].figure
    g = ref.gear_norm.to_numpy()
    moving = np.flatnonzero(np.diff(g) != 0)
    tol = {"theta_deg": theta_tolerance(ref), "tas_kt": TOL_TAS_KT, "alt_ft": TOL_ALT_FT}
    for i, (ch, label) in enumerate(CHANNELS):
        ax, axr = axes[i][0], axes[i][1]
        for model in ("reference", "linear", "nonlinear"):
            log = replays.get((case, model, loop))
            if log is None:
                continue
            if model == "reference":
                ax.plot(log.t_s, log[ch], color="0.2", lw=4.0, alpha=0.35, label=model)
            else:
                ax.plot(
                    log.t_s, log[ch], color=COLORS[model], lw=1.2, ls="-" if model != "linear" else "--", label=model
                )
            band = bands.get((case, model, loop))
            if band is not None:
                ax.fill_between(
                    band.t_s,
                    band[f"{ch}_lo"],
                    band[f"{ch}_hi"],
                    color=COLORS[model],
                    alpha=0.18,
                    lw=0,
                    label=f"{model}: 95 % band",
                )
                n = min(len(ref), len(band))
                r = ref[ch].to_numpy()[:n]
                axr.fill_between(
                    band.t_s[:n],
                    band[f"{ch}_lo"].to_numpy()[:n] - r,
                    band[f"{ch}_hi"].to_numpy()[:n] - r,
                    color=COLORS[model],
                    alpha=0.18,
                    lw=0,
                )
            if model != "reference":
                n = min(len(ref), len(log))
                axr.plot(
                    log.t_s[:n],
                    log[ch].to_numpy()[:n] - ref[ch].to_numpy()[:n],
                    color=COLORS[model],
                    lw=1.1,
                    ls="-" if model != "linear" else "--",
                    label=f"{model} - reference",
                )
        if ch in tol:
            axr.axhspan(-tol[ch], tol[ch], color="tab:green", alpha=0.12, label="Part 60 tolerance")
        axr.axhline(0, color="0.5", lw=0.6)
        ax.set_ylabel(label)
        axr.set_ylabel(f"error, {label}")
        for a in (ax, axr):
            if moving.size:
                a.axvspan(ref.t_s.iloc[moving[0]], ref.t_s.iloc[moving[-1] + 1], color="0.85", alpha=0.5, lw=0)
            a.grid(alpha=0.3)
            a.tick_params(labelsize=10)
    axes[0][0].legend(fontsize=10, loc="best")
    axes[0][1].legend(fontsize=9, loc="best")
    axes[-1][0].set_xlabel("time [s]  (grey: gear travelling)")
    axes[-1][1].set_xlabel("time [s]")
    fig.suptitle(f"{case}, {loop} loop: reference vs identified linear and nonlinear gear models", fontsize=13)
    return fig


def _save_plot(replays: dict, case: str, loop: str, path: Path, bands: dict | None = None) -> str:
    fig = plot_case(replays, case, loop, axes=emptied_axes("replay_case", FIGSIZE, _case_axes), bands=bands)
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=100, format="png"))
    return str(path)


def write_report(results: Path, names: list[str] | None = None, jobs: int = 1) -> dict[str, str]:
    """metrics.csv and metrics.txt over every stored replay, and one figure per
    case and loop for the cases ``names`` selects (all by default), drawn by ``jobs``
    worker processes (in this one if 1)."""
    results = Path(results)
    replays = load_replays(results, names)
    out = results / "replays"
    summary, bands = load_bands(results)
    df = metrics(load_replays(results) if names else replays, summary)
    clean_temporaries(out)
    written = tool_text()  # the provenance: a column of the table, a line of the text
    atomic_write(out / "metrics.csv", lambda tmp: df.assign(tool=written).to_csv(tmp, index=False))
    atomic_write(out / "metrics.txt", lambda tmp: Path(tmp).write_text(metrics_text(df) + f"\nWritten by {written}.\n"))
    files = {"metrics_csv": str(out / "metrics.csv"), "metrics_txt": str(out / "metrics.txt")}
    plots = out / "plots"
    plots.mkdir(exist_ok=True)
    todo = sorted({(c, lp) for c, m, lp in replays if m == "reference"})
    subsets = [{k: v for k, v in replays.items() if k[0] == case and k[2] == loop} for case, loop in todo]
    paths = pmap(
        _save_plot,
        [
            (
                sub,
                case,
                loop,
                plots / f"{case}__{loop}.png",
                {k: v for k, v in bands.items() if k[0] == case and k[2] == loop},
            )
            for sub, (case, loop) in zip(subsets, todo)
        ],
        jobs,
    )
    files.update({f"plot_{case}_{loop}": p for (case, loop), p in zip(todo, paths)})
    selected = df[df.case.isin({c for c, _, _ in replays})]
    files["table"] = metrics_text(selected)
    return files


# Monte Carlo bands (written by campaign.replays.bands; read here, without JSBSim)


def surfaces_file(results: Path) -> Path:
    return Path(results) / "identification" / "gear_surfaces.json"


def surfaces_sha(path: Path) -> str:
    """SHA-256 of the surfaces file the bands were drawn from."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def bands_doc_text(doc: dict) -> str:
    return json.dumps(doc, indent=1) + "\n"


def _bands_json(p: Path) -> dict | None:
    """``bands.json``, or None if it is missing or does not read (it is derived: drawn again, it is
    written whole)."""
    try:
        doc = json.loads(p.read_text())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and isinstance(doc.get("cases"), dict) else None


def stored_bands_doc(results: Path, sha: str) -> dict:
    """``bands.json`` as it stands if drawn from the same identification, else a new one."""
    doc = _bands_json(Path(results) / "replays" / "bands.json")
    return doc if doc is not None and doc.get("surfaces_sha256") == sha else {"cases": {}}


def drop_bands(results: Path, names: list[str]) -> None:
    """Forget the bands of re-flown cases: they were drawn about the replays they replace."""
    rep = Path(results) / "replays"
    p = rep / "bands.json"
    doc = _bands_json(p)
    if doc is None:
        return
    gone = [k for k in doc["cases"] if k.split("__")[0] in names]
    if not gone:
        return
    for k in gone:
        doc["cases"].pop(k)
        (rep / "bands" / f"{k}.parquet").unlink(missing_ok=True)
    text = bands_doc_text(doc)
    atomic_write(p, lambda tmp: Path(tmp).write_text(text))


def load_bands(results: Path) -> tuple[dict, dict[tuple[str, str, str], pd.DataFrame]]:
    """The stored bands that belong to the current identification: ``(summary per
    "case__model__loop", {(case, model, loop): band})``; empty if none."""
    rep = Path(results) / "replays"
    p, s = rep / "bands.json", surfaces_file(results)
    doc = _bands_json(p)
    if doc is None or not s.exists() or doc.get("surfaces_sha256") != surfaces_sha(s):
        return {}, {}
    frames = {}
    for name in doc.get("cases", {}):
        f = rep / "bands" / f"{name}.parquet"
        if f.exists():
            frames[tuple(name.split("__"))] = pd.read_parquet(f)
    return doc.get("cases", {}), frames
