"""``campaign identify``: every step from logs to tables, JSON, XML and plots."""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import shutil
import zlib
from collections.abc import Collection, Iterable, Iterator, Sequence
from itertools import islice
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from identify.compat import CompatResult, estimate
from identify.export import merge_into_aircraft, write_effects
from identify.logs import Log, LogError, LogHead, read_heads
from infra.model import folder_hash
from infra.provenance import tool
from identify.models import (
    COEFFS,
    PARAM_SUFFIX,
    REGRESSORS,
    GearSurface,
    Increments,
    LinearGearModel,
    PointFit,
    Reference,
    fit_baseline,
    fit_surface,
    increments,
    linear_models,
    reference_of,
    reference_order,
)
from identify.structure import DEFAULT, Structure
from identify.timedomain import METHODS, NAMES, refine_group
from infra.pool import imap, pmap

PAPER_POINTS = ("h02000_m0.30_f00_gup", "h02000_m0.30_f00_gdn")


class Packed(Sequence):
    """Results kept pickled and compressed, read back one at a time: 9,700 points' fits take 3 kB
    each so, against 21 kB as objects (their parameters are pandas Series).

    Parameters
    ----------
    blobs : iterable of bytes
        The items as :func:`pack` pickled them (on the workers: this process never builds them all).
    """

    def __init__(self, blobs: Iterable[bytes] = ()) -> None:
        self._blobs = list(blobs)

    def __len__(self) -> int:
        return len(self._blobs)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [pickle.loads(zlib.decompress(b)) for b in self._blobs[i]]
        return pickle.loads(zlib.decompress(self._blobs[i]))


@dataclass
class Identification:
    """Everything identified from one campaign."""

    fits: Sequence[PointFit]
    linear: dict[tuple, LinearGearModel]
    increments: dict[str, Increments]
    linear_surface: GearSurface | None
    nonlinear_surface: GearSurface | None
    arm_ft: tuple[float, float]  # AERORP aft of and above the CG [ft]
    compat: CompatResult | None = None  # instrument errors estimated and corrected before eq. (1)
    notes: tuple[str, ...] = ()  # why a model is missing
    method: str = "ee"  # the eq. (3) estimator asked for
    structure: Structure | None = None  # the time-domain structure asked for (before each point's terms left out)
    #: the points whose time-domain fit did not converge: ``{"point", "method", "reason"}`` each
    not_converged: tuple[dict, ...] = ()
    converged: int = 0  # points whose time-domain fit converged

    def to_dict(self) -> dict:
        """What the fits came from: the method, the structure, which points converged."""
        head = {"method": self.method, "method_name": NAMES[self.method]}
        if self.method != "ee":
            head.update(
                structure=(self.structure or DEFAULT).to_dict(),
                converged_points=self.converged,
                not_converged=list(self.not_converged),
            )
        return head


def _read(log: Log | LogHead, correct) -> Log:
    log = log.read()
    return correct(log) if correct is not None else log


def _reference(candidates: list, fallback, correct) -> Reference:
    return reference_of((_read(lg, correct) for lg in candidates), _read(fallback, correct))


def pack(item) -> bytes:
    """An item of :class:`Packed`: pickled, compressed (zlib's fastest level halves a fit)."""
    return zlib.compress(pickle.dumps(item, protocol=pickle.HIGHEST_PROTOCOL), 1)


def _fit(log: Log | LogHead, ref: Reference, correct, series: bool) -> bytes:
    fit = fit_baseline(_read(log, correct), ref)
    return pack(fit if series else fit.slim())


def _fit_group(
    logs: list, ref: Reference, correct, series: list[bool], method: str, structure: Structure, max_iter: int | None
) -> list[bytes]:
    """One status point's logs: equation error each, then the time-domain fit of them together."""
    logs = [_read(log, correct) for log in logs]
    fits = refine_group(logs, [fit_baseline(log, ref) for log in logs], method, structure, max_iter)
    return [pack(f if keep else f.slim()) for f, keep in zip(fits, series)]


def point_groups(logs: Iterable[Log | LogHead]) -> list[list]:
    """The excitation logs by status point (condition, the flap to 0.1 deg, gear position and weight), in
    order of first appearance: what a time-domain fit estimates together."""
    groups: dict[tuple, list] = {}
    for log in logs:
        if log.excitation:
            alt, mach, flap = log.condition
            key = (alt, mach, round(flap, 1), log.gear_down, log.meta["status_point"].get("weight_lb"))
            groups.setdefault(key, []).append(log)
    return list(groups.values())


def _increments(log: Log | LogHead, derivatives: dict, correct) -> Increments:
    return increments(_read(log, correct), derivatives).slim()


def identify_logs(
    logs: list[Log | LogHead],
    compatibility: bool = True,
    jobs: int = 1,
    series: Collection[str] | None = None,
    method: str = "ee",
    structure: Structure | None = None,
    max_iterations: int | None = None,
) -> Identification:
    """Baseline fits, linear gear models, increments and the eq. (9) surfaces.

    With ``compatibility`` the instrument errors are estimated first (from a sample of the
    logs) and every log is corrected for them and for its documented sensor positions as it
    is read (:mod:`identify.compat`). The per-point fits, then the increments, run on ``jobs``
    processes as the logs are read, one log a task: given :class:`identify.logs.LogHead` s,
    the memory does not grow with the samples of all logs, only with each point's results.

    Parameters
    ----------
    logs : list of Log or LogHead
    series : collection of str, optional
        The points whose fits keep their per-sample series (for their plots); None: every one.
    method : {"ee", "oe", "fe"}
        The eq. (3) estimator: equation error (the paper's least squares), output error or
        filter error (:mod:`identify.timedomain`, started from the equation error's estimates;
        each status point's excitation manoeuvres fitted together).
    structure : Structure, optional
        The time-domain model (:mod:`identify.structure`; default :data:`identify.structure.DEFAULT`,
        each point's unexcited terms left out).
    max_iterations : int, optional
        The time-domain estimator's iteration limit (default: its own).
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, not {method!r}")
    if max_iterations is not None and max_iterations < 1:
        raise ValueError(f"max_iterations must be at least 1, not {max_iterations}")
    compat = estimate(logs, jobs=jobs) if compatibility else None
    correct = compat.correct if compat is not None else None
    order = reference_order(logs)
    refs = dict(zip(order, pmap(_reference, [(*o, correct) for o in order.values()], jobs)))
    keep = lambda log: series is None or log.point in series  # noqa: E731
    if method == "ee":
        fits = Packed(
            imap(_fit, [(log, refs[log.condition], correct, keep(log)) for log in logs if log.excitation], jobs)
        )
    else:
        fits = Packed(
            b
            for group in imap(
                _fit_group,
                [
                    (
                        g,
                        refs[g[0].condition],
                        correct,
                        [keep(lg) for lg in g],
                        method,
                        structure or DEFAULT,
                        max_iterations,
                    )
                    for g in point_groups(logs)
                ],
                jobs,
            )
            for b in group
        )
    failed, converged = [], 0
    if method != "ee":
        for f in fits:
            if f.failure:
                failed.append({"point": f.point, **f.failure})
            else:
                converged += 1
    linear = linear_models(fits)
    moves = [log for log in logs if log.transition and log.condition in linear]
    incs = dict(
        zip(
            (log.point for log in moves),
            pmap(_increments, [(log, linear[log.condition].derivatives, correct) for log in moves], jobs),
        )
    )
    lin_surface = None
    if linear:
        lin_surface = fit_surface(
            [
                (
                    c,
                    m.alpha_trim_deg,
                    np.array([0.0, 1.0]),
                    {k: np.array([0.0, m.increment(k)]) for k in COEFFS},
                    {k: np.array([0.0, np.hypot(m.c0_up_bse.get(k, 0.0), m.c0_dn_bse.get(k, 0.0))]) for k in COEFFS},
                )
                for c, m in linear.items()
            ]
        )
    nl_surface = (
        fit_surface(
            [
                (
                    i.condition,
                    i.alpha_trim_deg,
                    i.grid,
                    i.smooth,
                    {k: np.where(i.grid > 0.0, v, 0.0) for k, v in i.se.items()},
                )
                for i in incs.values()
            ]
        )
        if incs
        else None
    )
    g = logs[0].meta["geometry"]  # imported logs may not give the AERORP: then it is taken at the CG
    arm = (
        (g.get("aerorp_x_in", 0.0) - g.get("cg_x_in", 0.0)) / 12.0,
        (g.get("aerorp_z_in", 0.0) - g.get("cg_z_in", 0.0)) / 12.0,
    )
    return Identification(
        fits,
        linear,
        incs,
        lin_surface,
        nl_surface,
        arm,
        compat,
        _why_none(logs, linear, incs),
        method,
        structure,
        tuple(failed),
        converged,
    )


def _why_none(logs: list[Log], linear: dict, incs: dict) -> tuple[str, ...]:
    """Why the gear models are missing, if they are."""
    notes = []
    if not linear:
        up = sorted({_cond_key(lg.condition) for lg in logs if lg.excitation and not lg.gear_down})
        dn = sorted({_cond_key(lg.condition) for lg in logs if lg.excitation and lg.gear_down})
        notes.append(
            "No linear gear model (eq. 4): it needs excitation manoeuvres gear up and gear down at one "
            f"condition; gear up at {', '.join(up) or 'none'}, gear down at {', '.join(dn) or 'none'}."
        )
    if not incs:
        moves = [lg for lg in logs if lg.transition]
        notes.append(
            "No nonlinear gear increments (eq. 8): "
            + (
                "no gear transition was logged."
                if not moves
                else f"the gear transitions ({', '.join(sorted({_cond_key(lg.condition) for lg in moves}))}) are at no "
                "condition with a linear gear model, whose derivatives they need."
            )
        )
    return tuple(notes)


def _method_lines(ident: Identification) -> list[str]:
    """The head of summary.txt for a time-domain identification: the method, the structure, and
    every point whose fit did not converge."""
    if ident.method == "ee":
        return []
    lines = [
        f"Method: {NAMES[ident.method]} ({ident.method}), each status point's excitation manoeuvres fitted "
        f"together; {ident.converged} point(s) converged, {len(ident.not_converged)} not.",
        f"Structure ({(ident.structure or DEFAULT).source}): {(ident.structure or DEFAULT).describe()}; "
        "each point's terms its records do not support are left out (listed with the point).",
        "",
    ]
    if ident.not_converged:
        lines += [
            f"NOT CONVERGED: {len(ident.not_converged)} point(s); their estimates are the equation error's, "
            "labelled ee:"
        ]
        lines += [f"  {d['point']}: {NAMES[d['method']]}: {d['reason']}" for d in ident.not_converged] + [""]
    return lines


def _cond_key(c: tuple) -> str:
    flap = f"{int(c[2]):02d}" if float(c[2]).is_integer() else f"{c[2]:g}"
    return f"h{int(c[0]):05d}_m{c[1]:.2f}_f{flap}"


def write_outputs(  # noqa: C901
    ident: Identification,
    out: Path,
    model_dir: Path | None,
    plots: str = "paper",
    jobs: int = 1,
) -> dict[str, str]:
    """Write tables (CSV, text), identification.json, XML and plots (on ``jobs`` processes) into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, str] = {}

    def parameter_rows(f: PointFit) -> Iterator[dict]:
        for c, res in f.fits.items():
            for r in ("const", *REGRESSORS):
                ok = r in res.params.index
                yield {
                    "point": f.point,
                    "gear": "down" if f.gear_down else "up",
                    "coefficient": c,
                    "parameter": f"{c}{PARAM_SUFFIX[r]}",
                    "estimate": float(res.params[r]) if ok else np.nan,
                    "std_error": float(res.bse[r]) if ok else np.nan,
                    "identifiable": ok,
                    "note": "" if ok else res.unexcited.get(r, ""),
                    "method": res.method,
                }

    def statistics_rows(f: PointFit) -> Iterator[dict]:
        for c, res in f.fits.items():
            yield {
                "point": f.point,
                "coefficient": c,
                "r2": res.rsquared,
                "resid_max": res.resid_max,
                "resid_rms": res.resid_rms,
                "rel_error_pct": res.rel_error_pct,
                "nobs": res.nobs,
                "not_identifiable": ";".join(res.unexcited),
                "method": res.method,
            }

    _csv_in_chunks(out / "baseline_parameters.csv", (r for f in ident.fits for r in parameter_rows(f)))
    _csv_in_chunks(out / "baseline_fit_statistics.csv", (r for f in ident.fits for r in statistics_rows(f)))
    lin_rows = []
    for cond, m in ident.linear.items():
        row = {"condition": _cond_key(cond), "alpha_trim_deg": m.alpha_trim_deg}
        for c in COEFFS:
            row.update({f"{c}0_gearup": m.c0_up[c], f"{c}0_gearDn": m.c0_dn[c], f"d{c}_gear": m.increment(c)})
            row.update({f"{c}{PARAM_SUFFIX[r]}": v for r, v in m.derivatives[c].items()})
        lin_rows.append(row)
    pd.DataFrame(lin_rows).to_csv(out / "linear_gear_model.csv", index=False)
    _csv_in_chunks(
        out / "gear_increments.csv",
        (
            {"point": p, "gear_norm": g, **{f"d{c}": float(i.smooth[c][k]) for c in COEFFS}}
            for p, i in ident.increments.items()
            for k, g in enumerate(i.grid)
        ),
    )
    files.update(
        {
            k: str(out / f"{k}.csv")
            for k in ("baseline_parameters", "baseline_fit_statistics", "linear_gear_model", "gear_increments")
        }
    )

    text = (
        ["Identification summary", "=" * 22, ""] + _method_lines(ident) + [*ident.notes] + ([""] if ident.notes else [])
    )
    if ident.linear:
        head = pd.DataFrame(
            [
                {
                    "condition": _cond_key(c),
                    "alpha_trim_deg": round(m.alpha_trim_deg, 2),
                    **{f"d{k}_gear": round(m.increment(k), 5) for k in COEFFS},
                }
                for c, m in sorted(ident.linear.items())
            ]
        )
        text += [
            "Linear gear increments (eq. 4): gear-down minus gear-up at the gear-up trim, per condition",
            head.to_string(index=False),
            "",
        ]
    if ident.increments:
        peaks = pd.DataFrame(
            [
                {
                    "point": p,
                    **{f"peak_d{k}": round(float(i.smooth[k][np.argmax(np.abs(i.smooth[k]))]), 5) for k in COEFFS},
                    **{f"d{k}_at_0.5": round(float(np.interp(0.5, i.grid, i.smooth[k])), 5) for k in COEFFS},
                }
                for p, i in sorted(ident.increments.items())
            ]
        )
        text += [
            "Nonlinear gear increments (eq. 8) along each transition: peak and value at delta_LG = 0.5",
            peaks.to_string(index=False),
            "",
        ]
    for f in ident.fits:
        if f.point in PAPER_POINTS:
            text += [f"Table 2 style, {f.point}", f.table().to_string(), ""]
    for cond, m in ident.linear.items():
        if _cond_key(cond) == PAPER_POINTS[0][:-4]:
            text += [
                f"Table 3 style (linear gear model), {_cond_key(cond)}",
                pd.DataFrame(
                    {
                        c: {
                            "C0_gearup": m.c0_up[c],
                            "C0_gearDn": m.c0_dn[c],
                            **{PARAM_SUFFIX[r]: v for r, v in m.derivatives[c].items()},
                        }
                        for c in COEFFS
                    }
                ).T.to_string(),
                "",
            ]
    if ident.nonlinear_surface:
        text += [
            "Eq. (9) designs chosen by leave-one-out cross-validation (flap/coefficient: design):",
            "  " + ", ".join(f"{k}: {v}" for k, v in ident.nonlinear_surface.to_dict()["designs"].items()),
            "",
        ]
    if ident.compat is not None:
        text += [ident.compat.summary(), ""]
        (out / "compatibility.json").write_text(json.dumps(ident.compat.to_dict(), indent=1, default=float) + "\n")
        files["compatibility"] = str(out / "compatibility.json")
    text += ["Per-point fits", ""]
    with open(out / "summary.txt", "w") as txt:  # the per-point fits as they are read back
        txt.write("\n".join(text))
        for f in ident.fits:
            txt.write("\n" + f.summary() + "\n")
    files["summary"] = str(out / "summary.txt")

    for kind, surface in (("linear", ident.linear_surface), ("nonlinear", ident.nonlinear_surface)):
        if surface is None:
            continue
        xml = write_effects(surface, kind, ident.arm_ft, out / f"gear_{kind}.xml")
        files[f"xml_{kind}"] = str(xml)
        if model_dir is not None and Path(model_dir).is_dir():
            files[f"aircraft_{kind}"] = str(merge_into_aircraft(model_dir, xml, out / f"aircraft_{kind}"))

    surfaces = {
        k: s.to_arrays() for k, s in (("linear", ident.linear_surface), ("nonlinear", ident.nonlinear_surface)) if s
    }
    if surfaces:
        (out / "gear_surfaces.json").write_text(json.dumps({"arm_ft": list(ident.arm_ft), **surfaces}) + "\n")
        files["surfaces"] = str(out / "gear_surfaces.json")

    points = (
        (
            f.point,
            {
                "gear": "down" if f.gear_down else "up",
                "condition": dict(zip(("alt_ft", "mach", "flap_deg"), map(float, f.condition))),
                "reference": {**vars(f.reference), "source": Path(f.reference.source).name},
                # the log, from this folder (it is staged beside its final place): campaign model reads it
                **({"log": os.path.relpath(f.path, out)} if Path(f.path).is_file() else {}),
                "method": f.timedomain["method"] if f.timedomain and not f.failure else "ee",
                **({"not_converged": f.failure} if f.failure else {}),
                **({"timedomain": f.timedomain} if f.timedomain else {}),
                **{c: f.fits[c].to_dict() for c in COEFFS},
            },
        )
        for f in ident.fits
    )
    doc = {
        "tool": tool(),
        **ident.to_dict(),
        "points": _LATER[0],
        "linear": {_cond_key(c): m.to_dict() for c, m in ident.linear.items()},
        "increments": _LATER[1],
        "surfaces": {
            k: s.to_dict() for k, s in (("linear", ident.linear_surface), ("nonlinear", ident.nonlinear_surface)) if s
        },
        "notes": list(ident.notes),
        "files": {k: str(Path(v).relative_to(out)) for k, v in files.items()},
    }
    with open(out / "identification.json", "w") as f:
        _dump_streaming(doc, [points, ((p, i.to_dict()) for p, i in ident.increments.items())], f)
    files["json"] = str(out / "identification.json")
    if plots != "none":
        files.update(_plots(ident, out / "plots", plots, jobs))
    return files


#: Where :func:`_dump_streaming` writes objects one entry at a time, in this order.
_LATER = ("@@first object written one entry at a time@@", "@@second object written one entry at a time@@")


def _dump_streaming(doc: dict, objects: list[Iterator[tuple[str, object]]], f) -> None:
    """``json.dump(doc, f, indent=1)`` and a newline, byte for byte, with each value ``_LATER[k]``
    written as the object of ``objects[k]`` (key, value pairs) encoded one entry at a time:
    thousands of points' fits are never held together as JSON or as dicts."""
    text = json.dumps(doc, indent=1, default=float)
    for marker, items in zip(_LATER, objects):
        head, text = text.split(json.dumps(marker))
        f.write(head)
        pad = " " * (head.rsplit("\n", 1)[-1].index('"') + 1)  # the key's indentation, one more for its object
        first = True
        for key, value in items:
            f.write(
                ("{\n" if first else ",\n")
                + pad
                + json.dumps(key)
                + ": "
                + json.dumps(value, indent=1, default=float).replace("\n", "\n" + pad)
            )
            first = False
        f.write("{}" if first else "\n" + pad[:-1] + "}")
    f.write(text + "\n")


def _csv_in_chunks(path: Path, rows: Iterable[dict], chunk: int = 4096) -> None:
    """``pd.DataFrame(list(rows)).to_csv(path, index=False)``, byte for byte, a chunk of rows at a time."""
    rows = iter(rows)
    with open(path, "w", newline="") as f:
        part = list(islice(rows, chunk))
        pd.DataFrame(part).to_csv(f, index=False)
        while part:
            part = list(islice(rows, chunk))
            if part:
                pd.DataFrame(part).to_csv(f, index=False, header=False)


def _plots(ident: Identification, out: Path, which: str, jobs: int = 1) -> dict[str, str]:
    """The figures, drawn on ``jobs`` worker processes."""
    out.mkdir(parents=True, exist_ok=True)
    incs = list(ident.increments.values())
    todo = [
        (f"plot_fit_{f.point}", "fit", (f, f.t_s), out / f"fit_{f.point}.png")
        for f in ident.fits
        if which == "all" or f.point in PAPER_POINTS
    ]
    if incs:
        todo += [
            (f"plot_{name}", name, (incs,), out / f"{name}.png")
            for name in ("alpha_during_gear_transitions", "gear_increments")
        ]
    pmap(_draw, [(kind, args, path) for _, kind, args, path in todo], jobs)
    return {key: str(path) for key, _, _, path in todo}


def _draw(kind: str, args: tuple, path: Path) -> None:
    from matplotlib.figure import Figure

    from identify import plots
    from identify.figures import emptied_axes

    if kind == "fit":  # drawn for every point: on one figure per process
        plots.plot_fit(*args, axes=emptied_axes("fit", plots.FIT_SIZE, plots.fit_axes)).savefig(path, dpi=110)
        return
    if kind == "alpha_during_gear_transitions":
        fig = plots.plot_alpha_transitions(*args, ax=plots.alpha_axes(Figure(figsize=plots.ALPHA_SIZE)))
    else:
        fig = plots.plot_increments(*args, axes=plots.increments_axes(Figure(figsize=plots.INCREMENTS_SIZE)))
    fig.savefig(path, dpi=110)


def identify_campaign(
    results: Path,
    out: Path | None = None,
    model_dir: Path | None = None,
    plots: str = "paper",
    jobs: int = 1,
    method: str = "ee",
    structure: Structure | None = None,
    max_iterations: int | None = None,
) -> tuple[dict[str, str], Identification]:
    """Identify everything from a campaign folder; return the files written and the identification
    (:func:`identify_into`).

    The outputs are written into a staging folder beside ``out`` and swapped in
    when complete: a killed identification leaves the previous results, never a
    mixture.
    """
    results = Path(results)
    final = _writable((Path(out) if out else results / "identification").resolve())
    logs = read_heads(results)
    if not logs:
        raise LogError(f"{results}: no logs of flown points to identify from")
    if model_dir is None:
        man = results / "manifest.json"
        if man.exists():
            model_dir = json.loads(man.read_text()).get("settings", {}).get("aircraft")
    return identify_into(
        logs,
        final,
        model_dir,
        plots,
        jobs,
        method,
        source_stamp(results, model_dir, plots, method, structure, max_iterations),
        structure,
        max_iterations,
    )


def _writable(final: Path) -> Path:
    """``final``, once what a killed identification left there is undone, if it may be (re)written."""
    recover(final)
    if final.exists() and (
        not final.is_dir() or (any(final.iterdir()) and not (final / "identification.json").exists())
    ):
        raise LogError(f"{final}: exists and holds no identification; will not overwrite (choose another --out)")
    return final


def identify_into(
    logs: list[Log | LogHead],
    out: Path,
    model_dir: str | Path | None = None,
    plots: str = "paper",
    jobs: int = 1,
    method: str = "ee",
    stamp: dict | None = None,
    structure: Structure | None = None,
    max_iterations: int | None = None,
) -> tuple[dict[str, str], Identification]:
    """:func:`identify_logs` and :func:`write_outputs` into ``out``, written into a staging folder beside
    it and swapped in when complete (a killed identification leaves the previous results, never a
    mixture); ``stamp`` (:func:`source_stamp`) is kept beside them as ``source.json``.

    Returns
    -------
    files : dict
        What was written, by kind (``json``, ``summary``, ``xml_linear``...), as paths in ``out``.
    identification : Identification
    """
    final = _writable(Path(out).resolve())
    ident = identify_logs(
        logs,
        jobs=jobs,
        series={"all": None, "none": ()}.get(plots, PAPER_POINTS),
        method=method,
        structure=structure,
        max_iterations=max_iterations,
    )
    stage = _sibling(final, "partial")
    files = write_outputs(ident, stage, Path(model_dir) if model_dir else None, plots, jobs)
    if stamp is not None:
        (stage / SOURCE).write_text(json.dumps(stamp, indent=1) + "\n")
    _swap(stage, final)
    return {k: str(final / Path(v).relative_to(stage)) for k, v in files.items()}, ident


#: What an identification was made from (:func:`source_stamp`), in its folder.
SOURCE = "source.json"


def source_stamp(
    results: Path,
    model_dir: str | Path | None,
    plots: str,
    method: str,
    structure: Structure | None = None,
    max_iterations: int | None = None,
) -> dict:
    """What an identification of ``results`` depends on: the SHA-256 of the campaign's manifest and of
    every log file beside it (names and bytes), of the model folder merged into, the options (a
    structure by its content) and the tool's version (another version identifies again). Paths are
    left out: a copy of the folder has the same stamp."""
    h = hashlib.sha256()
    for f in sorted(
        p for p in Path(results).iterdir() if p.is_file() and (p.name == "manifest.json" or p.suffix in LOG_SUFFIXES)
    ):
        h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
    model = folder_hash(Path(model_dir)) if model_dir is not None and Path(model_dir).is_dir() else None
    extra = {}
    if structure is not None:
        extra["structure"] = {k: v for k, v in structure.to_dict().items() if k != "source"}
    if max_iterations is not None:
        extra["max_iterations"] = max_iterations
    return {
        "logs_sha256": h.hexdigest(),
        "model_sha256": model,
        "plots": plots,
        "method": method,
        **extra,
        "tool": tool(),
    }


#: The files of a campaign folder an identification reads.
LOG_SUFFIXES = (".parquet", ".csv", ".json")


def up_to_date(
    results: Path,
    plots: str = "paper",
    method: str = "ee",
    structure: Structure | None = None,
    max_iterations: int | None = None,
) -> Path | None:
    """``results/identification`` if it was made, complete, from the logs and options that are there now
    (:func:`source_stamp`, the manifest's aircraft as the model); else None. A killed identification is
    undone first (:func:`recover`)."""
    results = Path(results)
    final = results / "identification"
    recover(final)
    try:
        kept = json.loads((final / SOURCE).read_text())
    except (OSError, ValueError):
        return None
    if not (final / "identification.json").is_file():
        return None
    model = json.loads((results / "manifest.json").read_text()).get("settings", {}).get("aircraft")
    return final if kept == source_stamp(results, model, plots, method, structure, max_iterations) else None


def _sibling(folder: Path, what: str) -> Path:
    return folder.parent / f".{folder.name}.{what}"


def recover(folder: Path) -> None:
    """Undo what a killed identification left beside ``folder``: its half-written staging
    folder goes; if it died between moving the old results aside and the new ones in, the old
    ones come back."""
    folder, old = Path(folder), _sibling(Path(folder), "old")
    shutil.rmtree(_sibling(folder, "partial"), ignore_errors=True)
    if old.is_dir():
        if folder.exists():
            shutil.rmtree(old)
        else:
            os.rename(old, folder)


def _swap(stage: Path, final: Path) -> None:
    """Put the complete ``stage`` in place of ``final``: readers see the old results or the new
    ones, never a mixture."""
    old = _sibling(final, "old")
    if final.exists():
        os.rename(final, old)
    os.rename(stage, final)
    shutil.rmtree(old, ignore_errors=True)
