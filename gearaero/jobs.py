"""The everyday jobs from Python: fly, identify, model, diagnose, plan, report.

Each is the ``campaign`` command of the same name (the same code: :mod:`campaign.orchestration.job`,
:func:`identify.pipeline.identify_campaign`, :func:`campaign.modelling.build.build_model`,
:func:`campaign.diagnosis.run.run_diagnosis`,
:func:`campaign.design.plan.plan`, :mod:`campaign.reports.report`) and returns a results object
with ``summary()`` and ``to_dict()``. What a command prints, a job logs (the ``gearaero``
logger, level INFO). Bad input raises :class:`UserError` with one line naming the file and the
field; nothing already on disk is overwritten.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

from campaign.errors import UserError
from gearaero.results import (
    CampaignResult,
    DiagnosisResult,
    IdentificationResult,
    ModelResult,
    PlanResult,
    ReportResult,
)
from identify.logs import Log, LogError

LOG = logging.getLogger("gearaero")
LOG.addHandler(logging.NullHandler())


def _say(into: list):
    def say(text: str) -> None:
        into.append(text)
        LOG.info(text)

    return say


def _folder(data) -> Path | None:
    """The folder a results object or a path names, if it is one."""
    if isinstance(data, CampaignResult):
        return data.folder
    if isinstance(data, (str, Path)):
        return Path(data)
    return None


def fly(  # noqa: PLR0913
    matrix: str | Path | None = None,
    out: str | Path | None = None,
    *,
    jobs: int = 1,
    noise: str | None = None,
    instruments: str | Path | None = None,
    aircraft: str | Path | None = None,
    effects: str | Path | None = None,
    seed: int = 0,
    identify: bool = True,
    replay: bool = True,
    cases: str | Path | None = None,
    cluster: str | None = None,
    progress: bool = False,
) -> CampaignResult:
    """Fly a flight-test campaign: trim and fly every status point of a matrix, identify the gear models
    and replay the Part 60 cases on them, and write the report (``campaign run``).

    A folder that holds the same campaign already is resumed: points flown are kept, and so are an
    identification and replays made from the same logs.

    Parameters
    ----------
    matrix : str or Path, optional
        Test-matrix TOML (default: the paper's Fig. 3 matrix, shipped).
    out : str or Path, optional
        The campaign folder (default ``results/<matrix name>`` in the working directory).
    jobs : int
        Worker processes (local).
    noise : str, optional
        A shipped instrument profile: ``"none"`` (perfect instruments, the default) or
        ``"flight-test"`` (50 Hz, no pitch acceleration, nose-boom vanes, noise, light turbulence).
    instruments : str or Path, optional
        An instrument profile TOML instead of ``noise``.
    aircraft : str or Path, optional
        JSBSim aircraft folder holding ``<name>.xml`` (default: the shipped 737-800).
    effects : str or Path, optional
        Effect overlay XML that makes the model the "real aeroplane" (default: the shipped 737's
        reference overlay); ``"none"`` for the bare model.
    seed : int
        Campaign seed: the same seed flies bit-identical logs.
    identify : bool
        Identify the models from the logs (``campaign run --no-identify`` if False).
    replay : bool
        Fly the replay cases on the identified models (``--no-replay`` if False).
    cases : str or Path, optional
        Replay cases TOML (default: the shipped five cases).
    cluster : str, optional
        ``tcp://HOST:PORT`` of a Dask scheduler that flies the points and the replays.
    progress : bool
        A progress bar on stderr.

    Returns
    -------
    CampaignResult
        ``summary()`` what the run said; ``metrics`` the Part 60 table; ``identification``;
        ``report`` the HTML page.
    """
    from campaign.orchestration.job import flight_config, run_job
    from campaign.orchestration.store import holding

    m, config = flight_config(matrix, aircraft, effects, seed, noise, instruments)
    folder = Path(out) if out is not None else Path("results") / m.name
    said: list[str] = []
    with holding(folder, "run"):
        status = run_job(
            m,
            config,
            folder,
            jobs,
            progress=progress,
            cluster=cluster,
            identify=identify,
            replay=replay,
            cases_file=cases,
            say=_say(said),
            warn=LOG.warning,
        )
    return CampaignResult(folder, status, said)


def identify(
    data,
    out: str | Path | None = None,
    *,
    method: str = "ee",
    jobs: int = 1,
    plots: str = "paper",
    model: str | Path | None = None,
    reuse: bool = True,
    structure: str | Path | None = None,
    max_iterations: int | None = None,
) -> IdentificationResult:
    """Identify the aerodynamic models from measured logs (``campaign identify``): eq. (1) coefficients
    after the data compatibility, eq. (3) fits per excitation manoeuvre, the linear (eq. 4) and
    nonlinear (eqs. 8-9) gear models, and their JSBSim XML merged into the model.

    Parameters
    ----------
    data : str, Path, CampaignResult or list of Log
        A campaign folder (or a folder of Parquet or CSV logs), the result of :func:`fly`, or logs in
        memory (:func:`gearaero.log_from_frame`, :func:`gearaero.read_logs`).
    out : str or Path, optional
        The identification folder; default ``<data>/identification`` for a folder (required for
        logs in memory).
    method : {"ee", "oe", "fe"}
        Eq. (3) estimator: equation error (the paper's least squares), output error, or filter
        error (for turbulent data). A point whose output-error or filter-error fit does not
        converge keeps its equation-error estimates, labelled ``ee``, and is listed in
        ``not_converged`` (``campaign identify`` exits with 1 when no point converged).
    jobs : int
        Worker processes for the per-point fits.
    plots : {"paper", "all", "none"}
        Fit plots for the paper's 2000 ft, Mach 0.3, flap-up points only, for every point, or none.
    model : str or Path, optional
        The model aircraft folder the gear models are merged into (default: the campaign's aircraft).
    reuse : bool
        For a campaign folder and the default ``out``: keep an identification made from the same
        logs, model, options and tool version (as :func:`fly` does) instead of computing it again.
    structure : str or Path, optional
        With ``oe`` or ``fe``: the model to fit, a TOML file (:mod:`identify.structure`); default the
        longitudinal model with lift and drag in alpha and Mach, each point's unexcited terms left out.
    max_iterations : int, optional
        With ``oe`` or ``fe``: the estimator's iteration limit.

    Returns
    -------
    IdentificationResult
        ``summary()``, ``to_dict()`` (``identification.json``), ``parameters`` and
        ``linear_gear_model`` tables, ``not_converged``, ``identification`` (the fits in memory,
        when computed).
    """
    from campaign.orchestration.job import convergence_lines, identify_job, time_domain_options
    from campaign.orchestration.store import holding

    folder = _folder(data)
    if folder is not None:
        from identify.pipeline import up_to_date

        if reuse and out is None and model is None and (folder / "manifest.json").exists():
            kept = up_to_date(
                folder, plots, method, time_domain_options(method, structure, max_iterations), max_iterations
            )
            if kept:
                LOG.info(f"identification in {kept}: made from these logs already, kept")
                return IdentificationResult(kept, {}, None, kept=True)
        with holding(folder, "identify"):
            files, ident = identify_job(
                folder,
                Path(out) if out else None,
                model,
                plots,
                jobs,
                method,
                say=LOG.info,
                structure=structure,
                max_iterations=max_iterations,
            )
        return IdentificationResult(Path(files["json"]).parent, files, ident)
    logs = list(data) if isinstance(data, Sequence) else None
    if not logs or not all(isinstance(lg, Log) for lg in logs):
        raise UserError("identify: data: expected a folder, a CampaignResult or a list of Log")
    if out is None:
        raise UserError("identify: out: needed for logs given in memory (the folder to write into)")
    from campaign.simulation.aircraft import check_aircraft_folder
    from identify.pipeline import identify_into

    if model:
        check_aircraft_folder(model)
    shape = time_domain_options(method, structure, max_iterations)
    try:
        files, ident = identify_into(
            logs, Path(out), model, plots, jobs, method, structure=shape, max_iterations=max_iterations
        )
    except LogError as exc:
        raise UserError(str(exc)) from None
    except ValueError as exc:  # an estimator's option
        raise UserError(f"identify: {exc}") from None
    for line in convergence_lines(ident):
        LOG.info(line)
    return IdentificationResult(Path(files["json"]).parent, files, ident)


def model(identification, out: str | Path, *, name: str | None = None) -> ModelResult:
    """A whole JSBSim aircraft from an identification (``campaign model``): metrics, mass and inertia
    from the logs' metadata, flight controls that take the logged surface positions through the standard
    ``fcs/`` properties, the identified eq. (3) aerodynamics (blended over Mach and flap between the
    conditions identified) and gear models, nominal lateral-directional terms, and the thrust as an
    external force along the body x axis (``external_reactions/thrust/magnitude`` [lbf]). The aircraft
    is loaded by JSBSim and trimmed at the start of each identified record.

    Parameters
    ----------
    identification : str, Path or IdentificationResult
        An identification folder (``identification.json``); the logs it was made from must be readable.
    out : str or Path
        The new aircraft folder (refused if it holds anything).
    name : str, optional
        The aircraft's name: the folder's name, which JSBSim needs (default).

    Returns
    -------
    ModelResult
        ``folder``, ``xml``, ``summary()`` (what was built, what is nominal, the trims) and
        ``to_dict()`` (``model.json``).
    """
    from campaign.modelling.build import build_model

    folder = identification.folder if isinstance(identification, IdentificationResult) else Path(identification)
    said: list[str] = []
    built = build_model(folder, Path(out), name, say=_say(said))
    return ModelResult(built.folder, built.name, said)


def diagnose(
    data,
    model: str | Path,
    out: str | Path,
    settings=None,
    *,
    plots: str = "key",
    jobs: int = 1,
    refine: str | None = None,
    bands: int = 0,
    cluster: str | None = None,
    progress: bool = False,
    held_out: list[str] | None = None,
) -> DiagnosisResult:
    """Find what a model gets wrong in measured data, extend it, and measure the gain (``campaign
    diagnose``).

    About every third flight condition is held out (or the logs ``held_out`` names); on the rest, the coefficient residuals
    (measured eq. (1) minus the model at the measured states) are searched by stepwise regression
    for causes, aerodynamic (coefficient and variables) or instrument errors (channel and
    error); a cause is named only if it is significant, larger than instrument noise can make
    it, and improves held-out data. The named terms are written as JSBSim functions into a copy
    of the model, and the held-out manoeuvres are replayed on both.

    Parameters
    ----------
    data : str, Path, CampaignResult, list of Log, or a list of those
        Measured logs: a campaign folder, a folder of Parquet or CSV logs, one file, or logs in
        memory; several read together (a campaign and the flights :func:`plan` designed). A plan
        reads its diagnosis's logs from disk again: give logs in memory to :func:`write_logs` first
        if a plan will follow.
    model : str or Path
        The model aircraft folder (``<name>/<name>.xml``), any JSBSim aircraft.
    out : str or Path
        A new folder for the diagnosis (refused if it holds anything).
    settings : DiagnosisSettings, optional
        Every decision threshold of the diagnosis (:class:`diagnose.config.DiagnosisSettings`, also
        ``gearaero.DiagnosisSettings``; None: the documented defaults). ``diagnosis.json`` records them.
    plots : {"key", "all", "none"}
        The overview and the held-out manoeuvres where the first cause acts, every held-out
        manoeuvre, or none.
    jobs : int
        Worker processes for the noise floor, the replays and the plots.
    refine : {"oe"}, optional
        Refine the extension's terms by output error through replays of the fitted logs.
    bands : int
        Monte Carlo draws of the extension (20 or more; 0: none) for bands on the held-out replays.
    cluster : str, optional
        ``tcp://HOST:PORT`` of a Dask scheduler for the residuals, noise realizations and replays.
    progress : bool
        A progress bar of the stages on stderr.
    held_out : list of str, optional
        The logs to hold out, by file name or stem (``campaign diagnose --held-out``).

    Returns
    -------
    DiagnosisResult
        ``verdict``, ``causes``, ``extended_aircraft``, ``summary()`` (``diagnosis.txt``),
        ``to_dict()`` (``diagnosis.json``).
    """
    from campaign.diagnosis.run import run_diagnosis
    from campaign.orchestration.job import html_report

    if isinstance(data, CampaignResult):
        data = data.folder
    elif isinstance(data, (list, tuple)):
        data = [d.folder if isinstance(d, CampaignResult) else d for d in data]
    out = Path(out)
    doc = run_diagnosis(
        data,
        Path(model),
        out,
        plots=plots,
        jobs=jobs,
        progress=progress,
        cluster=cluster,
        refine=refine,
        bands=bands,
        settings=settings,
        held_out=held_out,
    )
    html_report(out, LOG.info, LOG.warning)
    return DiagnosisResult(out, doc)


def plan(
    diagnosis,
    out: str | Path | None = None,
    *,
    budget_min: float | None = None,
    matrix: str | Path | None = None,
    jobs: int = 1,
    progress: bool = False,
) -> PlanResult:
    """Design the flights that separate the rival explanations a diagnosis could not tell apart
    (``campaign plan``): candidates are flown on the model, and those that separate the rivals most
    per flight minute are chosen within the budget.

    Parameters
    ----------
    diagnosis : str, Path or DiagnosisResult
        A diagnosis folder (``diagnosis.json``) whose logs are on disk.
    out : str or Path, optional
        A new folder for the plan (default ``<diagnosis>/plan``).
    budget_min : float, optional
        Flight minutes to spend [min] (default: a quarter of the minutes already flown).
    matrix : str or Path, optional
        Candidate points to choose from, a test-matrix TOML (default: around the diagnosis's conditions).
    jobs : int
        Worker processes flying the candidates.
    progress : bool
        A progress bar on stderr.

    Returns
    -------
    PlanResult
        ``matrix`` (the chosen flights as a matrix for :func:`fly`), ``summary()`` (``plan.txt``),
        ``to_dict()`` (``plan.json``).
    """
    from campaign.design.plan import plan as design

    folder = diagnosis.folder if isinstance(diagnosis, DiagnosisResult) else Path(diagnosis)
    result = design(
        folder, Path(out) if out else None, budget_min, str(matrix) if matrix else None, jobs, progress=progress
    )
    result.pop("text", None)
    return PlanResult(Path(out) if out else folder / "plan", result)


def report(folder) -> ReportResult:
    """Write ``report.html`` for a campaign or a diagnosis (``campaign report``): one self-contained
    page, figures inline. A campaign's opens with its summary: each Part 60 case and loop with
    each identified model's PASS/FAIL and smallest margin, the test identifiers and a sign-off
    block.

    Parameters
    ----------
    folder : str, Path, CampaignResult or DiagnosisResult
        A campaign folder (``manifest.json``) or a diagnosis folder (``diagnosis.json``).

    Returns
    -------
    ReportResult
        ``path``, ``kind`` and ``first_page`` (the summary's rows).
    """
    from campaign.reports.report import part60_results, write_report

    if isinstance(folder, (CampaignResult, DiagnosisResult)):
        folder = folder.folder
    folder = Path(folder)
    if not folder.is_dir():
        raise UserError(f"{folder}: not a folder")
    path = write_report(folder)
    if (folder / "diagnosis.json").exists():
        import json

        doc = json.loads((folder / "diagnosis.json").read_text())
        return ReportResult(path, "diagnosis", [{"verdict": doc["verdict"]}])
    return ReportResult(path, "campaign", part60_results(folder))
