"""The everyday jobs end to end, shared by the command line and the Python API (:mod:`gearaero`).

Each job says what it did through ``say`` (one line of text at a time: the command line prints
them, the API logs them) and returns what it wrote; bad input raises
:class:`campaign.errors.UserError` with a one-line message naming the file and the field.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

from campaign.errors import UserError

Say = Callable[[str], None]


def _warn(text: str) -> None:
    sys.stderr.write(f"campaign: warning: {text}\n")


def flight_config(
    matrix: str | Path | None = None,
    aircraft: str | Path | None = None,
    effects: str | Path | None = None,
    seed: int = 0,
    noise: str | None = None,
    instruments: str | Path | None = None,
    point_id: str | None = None,
):
    """The matrix and the flight configuration of a campaign, checked before anything flies.

    Parameters
    ----------
    matrix : path, optional
        Test-matrix TOML (default: the paper's Fig. 3 matrix).
    aircraft : path, optional
        JSBSim aircraft folder holding ``<name>/<name>.xml`` (default: the shipped 737-800).
    effects : path or "none", optional
        Effect overlay XML (default: the shipped 737's ``effects/reference.xml``, the "real
        aeroplane"); ``"none"`` for the bare model.
    seed : int
        Campaign seed.
    noise : str, optional
        A shipped instrument profile by name (``"none"``, ``"flight-test"``).
    instruments : path, optional
        An instrument profile TOML (instead of ``noise``).
    point_id : str, optional
        One status point of the matrix: only its flaps are checked.

    Returns
    -------
    (Matrix, FlightConfig)
    """
    from campaign.simulation.aircraft import (
        DEFAULT_AIRCRAFT,
        DEFAULT_EFFECTS,
        AircraftSource,
        check_aircraft_folder,
        load_effects,
    )
    from campaign.simulation.checks import check_overlay, check_weights
    from campaign.simulation.engine import FlightConfig, check_flaps
    from campaign.simulation.instruments import load_profile
    from campaign.simulation.matrix import load_matrix

    if noise is not None and instruments is not None:
        raise UserError("noise and instruments: give one instrument profile, not both")
    m = load_matrix(matrix)
    folder = check_aircraft_folder(aircraft or DEFAULT_AIRCRAFT)
    fx = load_effects(DEFAULT_EFFECTS if effects is None else effects)
    config = FlightConfig(
        AircraftSource(str(folder), fx),
        seed,
        load_profile(instruments or noise or "none"),
        m.maneuver_params,
        m.clmax_by_flap,
    )
    points = [m.point(point_id)] if point_id is not None else m.points
    check_overlay(config.aircraft)
    check_flaps(config.aircraft, [(f"{m.path}: {p.entry}.flap_deg", p.flap_deg) for p in points])
    check_weights(
        config.aircraft, [(f"{m.path}: {p.entry}.weight_lb", p.weight_lb) for p in points if p.weight_lb is not None]
    )
    return m, config


def html_report(folder: Path, say: Say = print, warn: Say = _warn) -> Path | None:
    """Write or refresh ``folder/report.html`` (:mod:`campaign.reports.report`) and say where it is. At
    the end of a run, a replay or a diagnosis, a report that cannot be written is said, not fatal:
    the results are on disk (``campaign report`` tries again)."""
    from campaign.reports.report import write_report

    try:
        path = write_report(folder)
    except (OSError, KeyError, ValueError, TypeError) as exc:
        warn(f"{folder}: report.html not written ({type(exc).__name__}: {exc})")
        return None
    say(f"report: {path}")
    return path


def identify_job(
    results: Path,
    out: Path | None = None,
    model: str | Path | None = None,
    plots: str = "paper",
    jobs: int = 1,
    method: str = "ee",
    say: Say = print,
    structure: str | Path | None = None,
    max_iterations: int | None = None,
):
    """Identify a campaign folder (or a folder of logs) into ``out`` (default ``results/identification``)
    (:func:`identify.pipeline.identify_campaign`); say where, and for output or filter error how many
    points converged and, for each that did not, why.

    Returns
    -------
    files : dict
        The files written, by kind.
    identification : identify.pipeline.Identification
    """
    from campaign.simulation.aircraft import check_aircraft_folder
    from identify.logs import LogError
    from identify.pipeline import identify_campaign

    if model:
        check_aircraft_folder(model)
    shape = time_domain_options(method, structure, max_iterations)
    try:
        files, ident = identify_campaign(
            Path(results), out, Path(model) if model else None, plots, jobs, method, shape, max_iterations
        )
    except LogError as exc:
        raise UserError(str(exc)) from None
    except KeyboardInterrupt:  # the staging folder goes now, not at the next identification
        from identify.pipeline import recover

        recover(Path(out) if out else Path(results) / "identification")
        raise
    say(
        f"identification ({method}) in {Path(files['json']).parent}: "
        f"{sum(1 for k in files if k.startswith('plot'))} plots, "
        f"{', '.join(Path(v).name for k, v in files.items() if k.startswith('xml'))}"
    )
    for line in convergence_lines(ident):
        say(line)
    return files, ident


def time_domain_options(method: str, structure: str | Path | None, max_iterations: int | None):
    """The structure file read (None: the default), once the options are checked against the method."""
    from identify.structure import StructureError, load_structure

    if method == "ee" and (structure is not None or max_iterations is not None):
        raise UserError(
            f"identify: {'--structure' if structure is not None else '--max-iterations'}: applies to "
            "the time-domain methods (--method oe or fe), not to equation error"
        )
    if max_iterations is not None and max_iterations < 1:
        raise UserError(f"identify: --max-iterations: must be at least 1, found {max_iterations}")
    if structure is None:
        return None
    try:
        return load_structure(structure)
    except StructureError as exc:
        raise UserError(str(exc)) from None


def convergence_lines(ident) -> list[str]:
    """What the terminal says of a time-domain identification's convergence (nothing for equation error)."""
    from identify.timedomain import NAMES

    if ident.method == "ee":
        return []
    name, bad = NAMES[ident.method], ident.not_converged
    lines = [f"{name}: {ident.converged} of {ident.converged + len(bad)} point(s) converged"]
    for d in bad:
        lines.append(
            f"NOT CONVERGED {d['point']}: {NAMES[d['method']]}: {d['reason']}; its estimates are the "
            "equation error's, labelled ee"
        )
    if bad and not ident.converged:
        lines.append(f"no point converged by {name}")
    return lines


def replay_job(
    results: Path,
    names: list[str] | None = None,
    cases_file: str | Path | None = None,
    jobs: int = 1,
    cluster: str | None = None,
    bands: int | None = None,
    resume: bool = False,
    say: Say = print,
    warn: Say = _warn,
) -> list[str]:
    """Fly the replay cases on the reference and the identified models, write the metrics, plots and
    the report; return the failures (one line each)."""
    from campaign.replays.bands import check_draws, load_surfaces, replay_bands
    from campaign.replays.replay import LOOPS, MODELS, load_cases, replayed_already, run_replays, select
    from campaign.replays.report import drop_bands, write_report

    results = Path(results)
    if not (results / "manifest.json").exists():
        raise UserError(f"{results}: no manifest.json (not a campaign folder)")
    cases = select(load_cases(cases_file), names)
    if bands is not None:
        check_draws(bands)
        load_surfaces(results)
    kept = replayed_already(results, cases) if resume else set()
    # bands were drawn about the replays about to be replaced
    drop_bands(results, [c.name for c in cases if not all((c.name, m, lp) in kept for m in MODELS for lp in LOOPS)])
    if kept:
        say(f"replays: {len(kept)} flights kept, flown already about this identification")
    failures = run_replays(results, cases, jobs, cases_file, cluster, kept)
    for why in failures:
        say(f"replay failed: {why}")
    if bands is not None and failures:
        say(f"bands not drawn: {len(failures)} replay(s) failed")
    elif bands is not None:
        replay_bands(results, cases, bands, jobs)
    files = write_report(results, names, jobs)
    say(files.pop("table"))
    say(f"replay logs, metrics and plots in {results / 'replays'}")
    html_report(results, say, warn)
    return failures


def run_job(
    matrix,
    config,
    out: Path,
    jobs: int = 1,
    progress: bool = False,
    cluster: str | None = None,
    identify: bool = True,
    replay: bool = True,
    cases_file: str | Path | None = None,
    say: Say = print,
    warn: Say = _warn,
) -> int:
    """``campaign run``: fly, identify and replay a campaign into ``out`` (held by the caller,
    :func:`campaign.orchestration.store.holding`), and write its report.

    Returns
    -------
    int
        The command's exit code: 0, or 1 if no point flew or a replay failed.
    """
    from campaign.orchestration.runner import run_campaign

    if cases_file and identify and replay:  # a bad cases file is refused before anything flies
        from campaign.replays.replay import load_cases
        from campaign.simulation.engine import check_flaps

        check_flaps(
            config.aircraft, [(f"{cases_file}: case {c.name}.flap_deg", c.flap_deg) for c in load_cases(cases_file)]
        )
    summary = run_campaign(matrix, config, out, jobs=jobs, progress=progress, cluster=cluster)
    say(summary.text())
    say(f"logs and manifest in {out}")
    if summary.all_failed:
        say("no point flew: nothing to identify")
        html_report(out, say, warn)
        return 1
    if not identify:
        html_report(out, say, warn)
        return 0
    from identify.pipeline import up_to_date

    kept = up_to_date(out)
    if kept:
        say(f"identification in {kept}: made from these logs already, kept")
    else:
        identify_job(out, None, None, "paper", jobs, say=say)
    if not replay:
        html_report(out, say, warn)
        return 0
    if not (out / "identification" / "aircraft_nonlinear").is_dir():
        say(
            "replays skipped: no gear models were identified (the matrix needs a condition flown "
            "gear up and gear down, with a gear extension)"
        )
        html_report(out, say, warn)
        return 0
    return 1 if replay_job(out, None, cases_file, jobs, cluster, resume=True, say=say, warn=warn) else 0
