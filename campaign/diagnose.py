"""``campaign diagnose``: show the discrepancy, name the cause, extend the model, measure the gain.

Identification (:mod:`identify.diagnosis`) works on the training logs; this
module splits the data, writes the extension into a copy of the model, and
measures the gain on held-out manoeuvres: coefficient residuals (JSBSim
evaluating both aircraft at the measured states) and replays (both aircraft
flown from the same trimmed start with the recorded inputs).
"""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from campaign.aircraft import AircraftSource, check_aircraft_folder, load_effects
from campaign.engine import FlightConfig, TrimError, fly
from campaign.errors import UserError
from campaign.matrix import StatusPoint
from identify.diagnosis import COEFFS, MIN_STD, Diagnosis, diagnose
from identify.residuals import residual_data
from identify.diagnosis_export import write_extension
from identify.evaluate import ModelEvaluator
from identify.export import merge_into_aircraft
from identify.logs import Log, LogError, read_campaign, read_csv, read_parquet
from identify.workers import Ahead, pmap, results, submit
from maneuvers.library import Recorded

REPLAY_CHANNELS = ("theta_deg", "alpha_deg", "q_dps", "tas_kt", "alt_ft")
G0 = 32.174049


def load_data(path: Path) -> list[Log]:
    """Measured logs: a campaign folder, a folder of CSV/Parquet logs, or one file."""
    path = Path(path)
    try:
        if path.is_dir():
            return read_campaign(path)
        if path.suffix == ".csv":
            return [read_csv(path)]
        if path.suffix == ".parquet":
            return [read_parquet(path)]
    except LogError as exc:
        raise UserError(str(exc)) from None
    raise UserError(f"{path}: not a campaign folder, a CSV or a Parquet log")


def split(logs: list[Log], every: int = 3) -> tuple[list[Log], list[Log]]:
    """Hold out every ``every``-th flight condition (all its manoeuvres)."""
    conds = sorted({log.condition for log in logs})
    if len(conds) < 2:
        raise UserError("--data: needs logs from at least two flight conditions (one is held out)")
    held = {c for i, c in enumerate(conds) if i % every == every - 1} or {conds[-1]}
    return [lg for lg in logs if lg.condition not in held], [lg for lg in logs if lg.condition in held]


def recorded(log: Log, head_s: float = 0.5, first: int = 3) -> tuple[StatusPoint, Recorded]:
    """The log's start as a status point and its inputs as offsets from that start.

    The flight condition is the mean of the first ``head_s`` (trimmed flight,
    sensor noise averaged out); the controls are referenced to their first
    ``first`` samples, because a hold may already be moving them.
    """
    d = log.data
    head = d[d.t_s < head_s].mean()
    ref = d.iloc[:first].mean()
    g0 = float(round(d.gear_norm.iloc[0]))
    moving = np.flatnonzero(np.abs(d.gear_norm.to_numpy() - g0) > 1e-6)
    gear_cmd = np.full(len(d), g0)
    if moving.size:  # the command set before step k moves the gear in row k
        gear_cmd[moving[0]:] = round(float(d.gear_norm.iloc[-1]))
    flap = round(float(head.flap_deg), 3)
    point = StatusPoint(float(head.alt_ft), float(head.mach), flap, g0 == 1.0, float(head.mass_slug) * G0)
    man = Recorded(g0, tuple(d.elevator_deg - ref.elevator_deg), tuple(d.stabilizer_deg - ref.stabilizer_deg),
                   tuple(d.throttle_norm - ref.throttle_norm), tuple(gear_cmd), name=f"replay-{log.maneuver}")
    return point, man


def replay(log: Log, source: AircraftSource) -> pd.DataFrame | None:
    """Fly the log's inputs on an aircraft from a trim at the log's start."""
    point, man = recorded(log)
    try:
        return fly(point, man, FlightConfig(source)).log
    except TrimError:
        return None


def replay_errors(measured: pd.DataFrame, flown: pd.DataFrame | None) -> dict[str, float]:
    if flown is None:
        return {ch: float("nan") for ch in REPLAY_CHANNELS}
    n = min(len(measured), len(flown))
    return {ch: float(np.max(np.abs(flown[ch].to_numpy()[:n] - measured[ch].to_numpy()[:n])))
            for ch in REPLAY_CHANNELS}


#: The stages the progress bar counts, in order.
STAGES = ("data compatibility", "instrument delays", "residuals", "stepwise", "noise floor", "instrument reach",
          "verdict", "extension", "replays", "plots")


#: Which held-out logs get plots of their own: ``key`` those where the first aerodynamic cause acts
#: (without one, those with the largest residual of each coefficient), ``all`` every one.
PLOTS = ("key", "all", "none")


def run_diagnosis(data_path: Path, model_dir: Path, out: Path, plots: str | bool = "key", jobs: int = 1,
                  progress: bool = False) -> dict:
    """The whole diagnosis; returns what ``diagnosis.json`` holds.

    Parameters
    ----------
    data_path, model_dir, out : Path
        Measured logs (:func:`load_data`), the model aircraft folder, a new report folder.
    plots : {"key", "all", "none"} or bool
        Which plots to draw (:data:`PLOTS`; True is ``key``, False ``none``). The overview of
        the residuals against each cause is always drawn unless ``none``.
    jobs : int
        Worker processes for the noise floor, the replays and the plots.
    progress : bool
        A progress bar of the stages on stderr.
    """
    plots = {True: "key", False: "none"}.get(plots, plots)
    if plots not in PLOTS:
        raise UserError(f"plots: {plots!r} is not one of {', '.join(PLOTS)}")
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise UserError(f"{out}: exists and is not empty; will not overwrite (choose another --out)")
    model = check_aircraft_folder(model_dir)
    logs = load_data(data_path)
    train, held = split(logs)
    try:
        evaluator = ModelEvaluator(model)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    bar = tqdm(total=len(STAGES), unit="stage", disable=not progress, bar_format="{l_bar}{bar}| {n}/{total} stages "
               "[{elapsed}]")
    src_model = AircraftSource(str(model), load_effects(None))
    # the data compatibility runs on one core: a process of its own flies the model's replays meanwhile
    ahead = Ahead(replay, [(lg, src_model) for lg in held], jobs)

    def stage(name: str) -> None:
        if name != STAGES[0]:
            ahead.stop()
        bar.n = STAGES.index(name)
        bar.set_description(name)

    try:
        diag = diagnose(train, evaluator, held, jobs=jobs, progress=stage)
    except ValueError as exc:  # logs the model cannot be set to (a flap angle it does not have)
        evaluator.close()
        bar.close()
        raise UserError(str(exc)) from None
    finally:
        ahead.stop()
    out.mkdir(parents=True, exist_ok=True)
    doc: dict = {"discrepancy": diag.discrepancy,
                 "verdict": "discrepancy" if diag.discrepancy else "no significant discrepancy",
                 "causes": [c.to_dict() for c in diag.causes],
                 "rejected": [c.to_dict() for c in diag.rejected],
                 "largest_rejected": None if diag.discrepancy else diag.largest_rejected(),
                 "extension": None, "extension_xml": None, "gain": {},
                 "alternatives": {c: r.alternatives for c, r in diag.results.items()},
                 "noise_estimated": diag.noise,
                 "data_compatibility": diag.compat.to_dict() if diag.compat else None,
                 "unset_inputs": [{"property": u.name, "held_at": u.value} for u in diag.unset],
                 "data": {"path": str(data_path), "logs": len(logs), "train": [lg.path for lg in train],
                          "held_out": [lg.path for lg in held]},
                 "model": str(model), "plotted_logs": []}
    before = diag.held
    raw_held, held = held, diag.held_logs  # as corrected for instrument errors
    extended_eval = None
    if diag.aero_causes:
        stage("extension")
        xml = write_extension(diag, out / "extension.xml")
        folder = merge_into_aircraft(model, xml, out / "extended_aircraft", replace_gear=False)
        doc["extension"], doc["extension_xml"] = str(folder), str(xml)
        extended_eval = ModelEvaluator(folder, jobs=jobs)
        after = residual_data(held, extended_eval)
        rms = {c: {"before": float(np.sqrt(np.mean(before[f"r_{c}"] ** 2))),
                   "after": float(np.sqrt(np.mean(after[f"r_{c}"] ** 2)))} for c in COEFFS}
        for v in rms.values():
            v["gain"] = v["before"] / v["after"] if v["after"] > 0 else float("inf")
        first = diag.aero_causes[0]
        top = first.coefficient
        acting = _exercised(before, first.variables)
        b, a = before[before.log.isin(acting)], after[after.log.isin(acting)]
        rms_acting = {c: {"before": float(np.sqrt(np.mean(b[f"r_{c}"] ** 2))),
                          "after": float(np.sqrt(np.mean(a[f"r_{c}"] ** 2)))} for c in COEFFS}
        for v in rms_acting.values():
            v["gain"] = v["before"] / v["after"] if v["after"] > 0 else float("inf")
        src_ext = AircraftSource(str(folder), load_effects(None))
        stage("replays")
        early = {i: fb for i, fb in ahead.finished().items() if recorded(held[i]) == recorded(raw_held[i])}
        calls = [(i, src) for i in range(len(held)) for src in (src_model, src_ext) if src is src_ext or i not in early]
        flown_now = dict(zip(calls, pmap(replay, [(held[i], src) for i, src in calls], jobs)))
        replays = {}
        flown = {}
        for i, lg in enumerate(held):
            fb, fa = early[i] if i in early else flown_now[i, src_model], flown_now[i, src_ext]
            flown[lg.path] = (fb, fa)
            eb, ea = replay_errors(lg.data, fb), replay_errors(lg.data, fa)
            replays[Path(lg.path).name] = {ch: {"before": eb[ch], "after": ea[ch]} for ch in REPLAY_CHANNELS}
        worst = {ch: {"before": max(r[ch]["before"] for r in replays.values()),
                      "after": max(r[ch]["after"] for r in replays.values())} for ch in REPLAY_CHANNELS}
        for v in worst.values():
            v["gain"] = v["before"] / v["after"] if v["after"] > 0 else float("inf")
        doc["gain"] = {"cause": first.label, "held_out_logs": [Path(lg.path).name for lg in held],
                       "cause_exercised_in": [Path(held[i].path).name for i in acting],
                       "residual_gain": rms_acting[top]["gain"], "coefficient": top,
                       "residual_rms": rms_acting, "residual_rms_all_held_out": rms,
                       "replay_max_error": worst, "replay_per_log": replays}
        if plots != "none":
            stage("plots")
            doc["plotted_logs"] = _plots(diag, held, before, after, flown, out, jobs,
                                         None if plots == "all" else acting)
    elif plots != "none":
        stage("plots")
        doc["plotted_logs"] = _plots(diag, held, before, None, {}, out, jobs,
                                     None if plots == "all" else _largest(before))
    bar.update(len(STAGES) - bar.n)
    bar.close()
    doc["summary"] = _report(diag, doc)
    (out / "diagnosis.json").write_text(json.dumps(doc, indent=1, default=float) + "\n")
    (out / "diagnosis.txt").write_text(doc["summary"])
    evaluator.close()
    if extended_eval:
        extended_eval.close()
    return doc


def _exercised(frame: pd.DataFrame, variables: list[str]) -> list[int]:
    """Held-out logs in which any of the cause's variables varies."""
    out = [int(i) for i, g in frame.groupby("log") if any(float(g[v].std()) >= MIN_STD[v] for v in variables)]
    return out or sorted(int(i) for i in frame.log.unique())


def _largest(frame: pd.DataFrame) -> list[int]:
    """The held-out logs with the largest residual RMS of each coefficient."""
    rms = frame.groupby("log")[[f"r_{c}" for c in COEFFS]].agg(lambda r: float(np.sqrt(np.mean(r ** 2))))
    return sorted({int(rms[col].idxmax()) for col in rms.columns})


def _plots(diag: Diagnosis, held: list[Log], before: pd.DataFrame, after: pd.DataFrame | None,
           flown: dict, out: Path, jobs: int = 1, which: list[int] | None = None) -> list[str]:
    """The overview, and the residual history and response of the held-out logs ``which`` (None: all);
    returns the names of the logs plotted."""
    (out / "plots").mkdir(exist_ok=True)
    which = range(len(held)) if which is None else which
    calls = [(Path(held[i].path).stem, held[i].data, before[before.log == i],
              after[after.log == i] if after is not None else None,
              *flown.get(held[i].path, (None, None)), out / "plots") for i in which]
    if jobs > 1:  # the overview too: the workers have matplotlib loaded, and this process waits anyway
        slim = replace(diag, held=None, logs=[], held_logs=[])  # what the overview draws, without the logs
        list(results(submit(_overview, [(slim, out / "plots")], jobs) + submit(_log_plots, calls, jobs)))
    else:
        _overview(diag, out / "plots")
        for args in calls:
            _log_plots(*args)
    return [Path(held[i].path).name for i in which]


def _overview(diag: Diagnosis, folder: Path) -> None:
    """The residuals of each coefficient against its first cause's variable."""
    import matplotlib.pyplot as plt

    from identify.diagnosis_plots import plot_residuals
    fig = plot_residuals(diag)
    fig.savefig(folder / "residuals_vs_cause.png", dpi=100)
    plt.close(fig)


def _log_plots(name: str, data: pd.DataFrame, before: pd.DataFrame, after: pd.DataFrame | None,
               flown_before: pd.DataFrame | None, flown_after: pd.DataFrame | None, folder: Path) -> None:
    """A held-out log's residual history and, if it was replayed, its response."""
    from identify.diagnosis_plots import (HISTORY_SIZE, RESPONSE_SIZE, history_axes, plot_residual_history,
                                          plot_response, response_axes)
    from identify.figures import emptied_axes
    fig = plot_residual_history(before, after, f"held out: {name}",
                                axes=emptied_axes("residual_history", HISTORY_SIZE, history_axes))
    fig.savefig(folder / f"residuals_{name}.png", dpi=90)
    if flown_before is not None:
        fig = plot_response(data, flown_before, flown_after, f"held out: {name}, same start and inputs",
                            axes=emptied_axes("response", RESPONSE_SIZE, response_axes))
        fig.savefig(folder / f"response_{name}.png", dpi=90)


def _names(files: list[str], n: int = 3) -> str:
    return ", ".join(files[:n]) + (f" and {len(files) - n} more" if len(files) > n else "")


def _report(diag: Diagnosis, doc: dict) -> str:
    lines = ["Diagnosis", "=========", "", f"data: {doc['data']['path']} ({doc['data']['logs']} logs, "
             f"{len(doc['data']['held_out'])} held out)", f"model: {doc['model']}", ""]
    lines.append(diag.summary())
    if diag.compat is not None:
        lines += ["", diag.compat.summary()]
    g = doc.get("gain")
    if g:
        lines += ["", f"Gain on {len(g['held_out_logs'])} held-out manoeuvres ({_names(g['held_out_logs'])}).",
                  f"Residual RMS where the first aerodynamic cause ({g['cause']}) acts, {len(g['cause_exercised_in'])} of them "
                  f"({_names(g['cause_exercised_in'])}):"]
        for c, v in g["residual_rms"].items():
            w = g["residual_rms_all_held_out"][c]
            lines.append(f"  {c}: {v['before']:.3g} -> {v['after']:.3g}  (x{v['gain']:.1f}); over every held-out "
                         f"manoeuvre {w['before']:.3g} -> {w['after']:.3g} (x{w['gain']:.1f})")
        lines.append("Replays of the held-out manoeuvres (same start, same inputs), worst error:")
        for ch, v in g["replay_max_error"].items():
            lines.append(f"  replay max error {ch}: {v['before']:.3g} -> {v['after']:.3g}  (x{v['gain']:.1f})")
        lines += ["", f"extension: {doc['extension']} (functions in {doc['extension_xml']})"]
    n = len(doc["plotted_logs"])
    if n and n < len(doc["data"]["held_out"]):
        lines.append(f"plots: the overview and {n} of the {len(doc['data']['held_out'])} held-out manoeuvres "
                     f"({'where the first cause acts' if g else 'with the largest residuals'}; --plots all: every one)")
    return "\n".join(lines) + "\n"
