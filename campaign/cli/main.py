"""Command line: ``campaign run | fly | identify | replay | plots | diagnose | report | import | model | points``."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from campaign.errors import UserError


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors and exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)


def shipped() -> list[str]:
    """Names of the shipped instrument profiles (:func:`campaign.simulation.instruments.shipped`, read here
    without importing that module's numerics: the command line must come up at once, for the
    worker server to start before the heavy imports)."""
    return sorted(p.stem for p in (Path(__file__).resolve().parents[1] / "simulation" / "profiles").glob("*.toml"))


def _jobs(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, found {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, found {n}")
    return n


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--matrix", help="test-matrix TOML (default: the paper's Fig. 3 matrix)")
    p.add_argument(
        "--aircraft", metavar="DIR", help="JSBSim aircraft folder holding DIR/<name>.xml (default: the shipped 737-800)"
    )
    p.add_argument(
        "--effects",
        metavar="FILE",
        help="effect overlay XML, or 'none' for the bare model "
        "(default: the shipped 737-800's effects/reference.xml, the 'real aeroplane')",
    )
    p.add_argument("--seed", type=int, default=0, help="campaign seed (default 0)")
    rec = p.add_mutually_exclusive_group()
    rec.add_argument(
        "--noise",
        choices=shipped(),
        default=None,
        help="a shipped instrument profile: 'none' (perfect instruments, the default) or "
        "'flight-test' (50 Hz, no qdot, nose-boom vanes, noise, light turbulence)",
    )
    rec.add_argument(
        "--instruments",
        metavar="FILE",
        help="instrument profile TOML (rate, omitted channels, turbulence, per-channel noise, "
        "bias, scale, lag, delay, position; see the user guide, docs/guide/instruments.md)",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="campaign",
        description=(
            "Fly a flight-test matrix on a JSBSim aircraft and log what flight-test "
            "instrumentation records, for landing-gear aerodynamics identification."
        ),
    )
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    run = sub.add_parser(
        "run",
        help="fly every status point of the matrix (the main job)",
        description="Trim and fly every status point of the matrix; resume if --out already holds the same campaign.",
    )
    _common(run)
    run.add_argument("--jobs", type=_jobs, default=1, help="parallel workers (default 1)")
    run.add_argument(
        "--cluster",
        metavar="tcp://HOST:PORT",
        help="fly the points and the replays on the Dask cluster whose scheduler is there (identification stays local)",
    )
    run.add_argument("--out", metavar="DIR", help="campaign folder (default results/<matrix name>)")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    run.add_argument("--no-identify", action="store_true", help="fly only: no identification, no replays")
    run.add_argument("--no-replay", action="store_true", help="fly and identify, but no replays")
    run.add_argument("--cases", metavar="FILE", help="replay cases TOML (default: the five shipped cases)")

    ident = sub.add_parser(
        "identify",
        help="identify the aerodynamic models from a campaign's logs",
        description="Eq. (1) coefficients, eq. (3) fits per 2-3-1-1, linear (eq. 4) and "
        "nonlinear (eqs. 8-9) gear models, JSBSim XML, tables, JSON, plots.",
    )
    ident.add_argument(
        "results",
        metavar="RESULTS_DIR",
        help="campaign folder (manifest.json + logs), or a folder of CSV logs with JSON sidecars",
    )
    ident.add_argument("--out", metavar="DIR", help="output folder (default RESULTS_DIR/identification)")
    ident.add_argument(
        "--model",
        metavar="AIRCRAFT_DIR",
        help="model aircraft to merge the identified gear models into (default: the campaign's aircraft)",
    )
    ident.add_argument(
        "--plots",
        choices=("paper", "all", "none"),
        default="paper",
        help="fit plots for the paper's 2000 ft/M0.3/flap-up points only (default), every point, or none",
    )
    ident.add_argument("--jobs", type=_jobs, default=1, help="parallel workers for the per-point fits (default 1)")
    ident.add_argument(
        "--method",
        choices=("ee", "oe", "fe"),
        default="ee",
        help="eq. (3) estimator: equation error (the paper's least squares, default), output "
        "error, or filter error (for turbulent data); see the README's Methods",
    )
    ident.add_argument(
        "--structure",
        metavar="FILE",
        help="with oe or fe: the model to fit, in TOML (terms per coefficient, states, outputs, "
        "inputs; docs/method/estimators.md); default: the longitudinal model, lift and drag in "
        "alpha and Mach, the moment also in q and the controls, each record's unexcited terms "
        "left out",
    )
    ident.add_argument(
        "--max-iterations",
        type=_jobs,
        metavar="N",
        help="with oe or fe: stop each fit after N iterations (a fit stopped before it converged is "
        "reported as not converged)",
    )

    fly = sub.add_parser(
        "fly",
        help="re-fly one status point",
        description="Re-fly one status point; its logs are bit-identical to the campaign's for the same options.",
    )
    fly.add_argument("point_id", metavar="POINT_ID", help="status point id, e.g. h02000_m0.30_f05_gdn")
    _common(fly)
    fly.add_argument("--out", metavar="DIR", required=True, help="folder for the logs")

    rep = sub.add_parser(
        "replay",
        help="fly the takeoff/landing cases on the reference and the identified models",
        description="Fly each replay case on the reference aircraft and on the model with the "
        "identified linear and nonlinear gear models, open and closed loop; write "
        "metrics and plots into RESULTS_DIR/replays.",
    )
    rep.add_argument("results", metavar="RESULTS_DIR", help="campaign folder, already identified")
    rep.add_argument("--case", action="append", metavar="NAME", help="case name or part of it (repeatable)")
    rep.add_argument("--cases", metavar="FILE", help="replay cases TOML (default: the five shipped cases)")
    rep.add_argument("--jobs", type=_jobs, default=1, help="parallel workers (default 1)")
    rep.add_argument(
        "--cluster", metavar="tcp://HOST:PORT", help="fly the replays on the Dask cluster whose scheduler is there"
    )
    rep.add_argument(
        "--bands",
        type=int,
        metavar="N",
        help="N >= 20 Monte Carlo draws of each identified gear model from its covariance, each "
        "flown through the cases on the local workers: shaded 95 %% bands in the plots and a "
        "Part 60 pass probability in metrics.csv",
    )

    plo = sub.add_parser(
        "plots",
        help="redraw the replay plots and metrics from stored logs (no flying)",
        description="Redraw the comparison plots (and metrics) from RESULTS_DIR/replays "
        "without flying or identifying again.",
    )
    plo.add_argument("results", metavar="RESULTS_DIR", help="campaign folder with replays")
    plo.add_argument("--case", action="append", metavar="NAME", help="case name or part of it (repeatable)")
    plo.add_argument("--jobs", type=_jobs, default=1, help="parallel workers drawing the plots (default 1)")

    dia = sub.add_parser(
        "diagnose",
        help="find what the model gets wrong in measured data, extend it, measure the gain",
        description="Residuals of the model against measured data, the cause named by "
        "stepwise regression, the model extended with it (JSBSim XML merged into a "
        "copy), and the gain on held-out manoeuvres.",
    )
    dia.add_argument(
        "--data",
        required=True,
        metavar="PATH",
        action="append",
        help="measured logs: a campaign folder, a folder of CSV logs with JSON sidecars, or a file "
        "(repeat to diagnose several together, e.g. a campaign and the flights `plan` designed)",
    )
    dia.add_argument("--model", required=True, metavar="AIRCRAFT_DIR", help="the model aircraft folder")
    dia.add_argument("--out", required=True, metavar="DIR", help="new folder for the report")
    which = dia.add_mutually_exclusive_group()
    which.add_argument(
        "--plots",
        choices=("key", "all", "none"),
        default="key",
        help="'key' (default): the overview and the held-out manoeuvres where the first cause acts "
        "(without a cause, those with the largest residuals); 'all': every held-out manoeuvre",
    )
    which.add_argument("--no-plots", action="store_true", help="no plots (same as --plots none)")
    dia.add_argument(
        "--jobs",
        type=_jobs,
        default=1,
        help="parallel workers for the noise floor, the replays and the plots (default 1)",
    )
    dia.add_argument(
        "--cluster",
        metavar="tcp://HOST:PORT",
        help="compute the residuals, sensitivities, noise realizations and replays on the Dask "
        "cluster whose scheduler is there (the plots stay on --jobs local workers)",
    )
    dia.add_argument(
        "--refine",
        choices=("oe",),
        help="refine the extension's terms by output error through JSBSim replays of the fitted logs, "
        "and report its gain beside the equation-error extension's",
    )
    dia.add_argument(
        "--bands",
        type=int,
        default=0,
        metavar="N",
        help="N Monte Carlo draws of the extension from its covariance: bands on the held-out replays "
        "where the cause acts, and their Part 60 pass probability (50 is usual; default 0: none)",
    )
    dia.add_argument(
        "--held-out",
        action="append",
        metavar="LOG",
        help="hold this log out (its file name or stem; repeatable) instead of about every third flight "
        "condition: the record of another flight that is to confirm the causes",
    )
    dia.add_argument("--quiet", action="store_true", help="no progress bar")

    rep = sub.add_parser(
        "report",
        help="write DIR/report.html: one self-contained page for a campaign or a diagnosis",
        description="One HTML file (figures inline, no network) for a campaign folder (coverage, "
        "trim and hold, identification, a Part 60 page per replay case, hashes) or a "
        "diagnosis folder (verdict, causes and evidence, replays, compatibility, "
        "rejected candidates, extension). run, replay and diagnose refresh it.",
    )
    rep.add_argument("folder", metavar="DIR", help="a campaign folder (manifest.json) or a diagnosis (diagnosis.json)")

    imp = sub.add_parser(
        "import",
        help="measured data in other names, units, rates and formats into logs",
        description="Convert measured files (CSV, whitespace ASCII, .mat, Parquet) into logs of the "
        "schema with a channel map (TOML), deriving what the source lacks; identify "
        "and diagnose then read DIR like a campaign folder.",
    )
    imp.add_argument("files", nargs="+", metavar="FILE", help="measured data files, one manoeuvre each")
    imp.add_argument(
        "--map",
        required=True,
        metavar="MAP.toml",
        help="channel map: names, units, constants, aircraft data (see docs/guide/import.md)",
    )
    imp.add_argument("--out", required=True, metavar="DIR", help="folder for the logs and the import report")

    mdl = sub.add_parser(
        "model",
        help="a whole JSBSim aircraft from an identification",
        description="Write a JSBSim aircraft folder from an identification: metrics, mass and "
        "inertia from the logs, flight controls taking the logged surface positions, "
        "the identified eq. (3) aerodynamics (blended over the conditions identified) "
        "and gear models, nominal lateral-directional terms, and the thrust as an "
        "external force; then trim it at the start of each identified record.",
    )
    mdl.add_argument(
        "identification",
        metavar="IDENTIFICATION_DIR",
        help="an identification folder (identification.json; the logs it was made from readable)",
    )
    mdl.add_argument("--out", required=True, metavar="DIR", help="new aircraft folder: DIR/NAME.xml")
    mdl.add_argument(
        "--name",
        metavar="NAME",
        help="the aircraft's name (default and only choice: DIR's name, as JSBSim finds NAME/NAME.xml)",
    )

    pla = sub.add_parser(
        "plan",
        help="design the flights that separate a diagnosis's rival explanations",
        description="Fly candidate status points and manoeuvres on the model, predict how far each "
        "would separate each rival explanation the diagnosis could not tell apart, and "
        "choose the flights that separate them most per flight minute: a matrix TOML "
        "(plan.toml) and a plan report.",
    )
    pla.add_argument("--diagnosis", required=True, metavar="DIR", help="a diagnosis folder (diagnosis.json)")
    pla.add_argument(
        "--budget-min",
        type=float,
        metavar="M",
        help="flight minutes to spend (default: a quarter of the minutes already flown)",
    )
    pla.add_argument(
        "--matrix", metavar="FILE", help="candidate points to choose from (default: around the diagnosis's conditions)"
    )
    pla.add_argument("--out", metavar="DIR", help="new folder for the plan (default DIR/plan)")
    pla.add_argument("--jobs", type=_jobs, default=1, help="parallel workers flying the candidates (default 1)")
    pla.add_argument("--quiet", action="store_true", help="no progress bar")

    pts = sub.add_parser(
        "points",
        help="list the status points of a matrix",
        description="List the status points of a matrix with their manoeuvres.",
    )
    pts.add_argument("--matrix", help="test-matrix TOML (default: the paper's Fig. 3 matrix)")
    return parser


def _config(args):
    from campaign.orchestration.job import flight_config

    return flight_config(
        args.matrix,
        args.aircraft,
        args.effects,
        args.seed,
        args.noise,
        args.instruments,
        args.point_id if args.command == "fly" else None,
    )


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    from infra.pool import one_blas_thread, sweep

    one_blas_thread()  # the matrices are small: a second BLAS thread costs 10x
    sweep()  # what killed runs left in the temporary folder
    return _main(args)


#: What each command's worker processes import: a server imports it once while the command
#: starts its own work, and the workers are forks of it (:mod:`infra.pool`).
PRELOAD = {
    "run": (
        "campaign.orchestration.runner",
        "identify.pipeline",
        "identify.plots",
        "campaign.replays.replay",
        "campaign.replays.report",
    ),
    "identify": ("identify.pipeline", "identify.plots"),
    "replay": ("campaign.replays.replay", "campaign.replays.report"),
    "plots": ("campaign.replays.report",),
    "diagnose": ("campaign.diagnosis.run", "diagnose.plots"),
}


def _preload(args) -> tuple[str, ...]:
    """:data:`PRELOAD` of the command, without the plots' modules (matplotlib, 30 MB in every worker) when it
    draws none."""
    if args.command == "diagnose" and (args.no_plots or args.plots == "none"):
        return tuple(m for m in PRELOAD["diagnose"] if not m.endswith(".plots"))
    return PRELOAD[args.command]


def _main(args) -> int:  # noqa: C901
    if getattr(args, "jobs", 1) > 1 and args.command in PRELOAD:
        from infra.pool import warm

        warm(_preload(args))
    try:
        if args.command == "points":
            from campaign.simulation.matrix import load_matrix

            for p in load_matrix(args.matrix).points:
                print(f"{p.id}  {' '.join(p.maneuvers)}")
            return 0
        if args.command == "plots":
            from campaign.replays.report import write_report
            from campaign.orchestration.store import holding

            results = Path(args.results)
            with holding(results, "plots"):
                files = write_report(results, args.case, args.jobs)
            print(files.pop("table"))
            n_plots = sum(1 for k in files if k.startswith("plot"))
            print(f"{n_plots} plots in {Path(args.results) / 'replays' / 'plots'}")
            return 0
        if args.command == "report":
            from campaign.reports.report import write_report

            folder = Path(args.folder)
            if not folder.is_dir():
                raise UserError(f"{folder}: not a folder")
            print(f"report: {write_report(folder)}")
            return 0
        if args.command == "diagnose":
            from campaign.diagnosis.run import run_diagnosis

            doc = run_diagnosis(
                [Path(d) for d in args.data],
                Path(args.model),
                Path(args.out),
                plots="none" if args.no_plots else args.plots,
                jobs=args.jobs,
                progress=not args.quiet and sys.stderr.isatty(),
                cluster=args.cluster,
                refine=args.refine,
                bands=args.bands,
                held_out=args.held_out,
            )
            print(doc["summary"])
            print(f"report in {args.out}")
            from campaign.orchestration.job import html_report

            html_report(Path(args.out))
            return 0
        if args.command == "model":
            from campaign.modelling.build import build_model

            build_model(Path(args.identification), Path(args.out), args.name, say=print)
            return 0
        if args.command == "plan":
            from campaign.design.plan import plan

            result = plan(
                Path(args.diagnosis),
                args.out and Path(args.out),
                args.budget_min,
                args.matrix,
                args.jobs,
                progress=not args.quiet and sys.stderr.isatty(),
            )
            print(result["text"], end="")
            return 0
        if args.command == "import":
            from campaign.importing.importer import import_files, report_text

            report = import_files(args.files, args.map, Path(args.out))
            print(report_text(report), end="")
            print(f"{len(report['logs'])} logs and import.txt in {args.out}")
            return 0
        from campaign.orchestration.store import holding

        if args.command == "replay":
            results = Path(args.results)
            if not (results / "manifest.json").exists():
                raise UserError(f"{results}: no manifest.json (not a campaign folder)")
            from campaign.orchestration.job import replay_job

            with holding(results, "replay"):
                return 1 if replay_job(results, args.case, args.cases, args.jobs, args.cluster, args.bands) else 0
        if args.command == "identify":
            from campaign.orchestration.job import identify_job

            results = Path(args.results)

            def identified():
                return identify_job(
                    results,
                    args.out and Path(args.out),
                    args.model,
                    args.plots,
                    args.jobs,
                    args.method,
                    structure=args.structure,
                    max_iterations=args.max_iterations,
                )[1]

            if not results.is_dir():
                ident = identified()
            else:
                with holding(results, "identify"):
                    ident = identified()
            return 1 if ident.not_converged and not ident.converged else 0  # no time-domain fit converged
        matrix, config = _config(args)
        if args.command == "run":
            out = Path(args.out) if args.out else Path("results") / matrix.name
            with holding(out, "run"):
                return _run(args, matrix, config, out)
        if args.command == "fly":
            from campaign.orchestration.runner import fly_point

            point = matrix.point(args.point_id)
            out = Path(args.out)
            with holding(out, "fly"):
                rec = fly_point(point, config, out, overwrite=False)
            if rec["status"] != "ok":
                print(f"{point.id}: failed: {rec['reason']}")
                return 1
            for f in rec["files"]:
                print(out / f)
            return 0
    except UserError as exc:
        sys.stderr.write(f"campaign: error: {exc}\n")
        return 2
    except RuntimeError as exc:
        if type(exc).__module__ != "_jsbsim":
            raise
        # a model JSBSim loads but cannot run (it reads a property nothing defines, such as
        # FlightGear's /sim/... tree); destroying it would throw again, and abort
        from infra.model import abandon_models

        abandon_models(exc.__traceback__)
        folder = getattr(args, "model", None) or getattr(args, "aircraft", None) or "the aircraft"
        sys.stderr.write(f"campaign: error: {folder}: JSBSim cannot run the model: {' '.join(str(exc).split())}\n")
        return 2
    except BrokenPipeError:  # e.g. `campaign points | head`
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except KeyboardInterrupt:
        import signal

        from infra.pool import stop_workers

        # a second Ctrl-C while the command stops (the terminal's, or one that arrives as the interpreter
        # exits, when it would end the process by the signal) stays pending: the exit status is 130
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        stop_workers()
        sys.stderr.write("campaign: interrupted; run the same command again to resume\n")
        return 130
    return 0


def _run(args, matrix, config, out: Path) -> int:
    """Fly, identify and replay a campaign into ``out`` (held by the caller)."""
    from campaign.orchestration.job import run_job

    return run_job(
        matrix,
        config,
        out,
        args.jobs,
        progress=not args.quiet and sys.stderr.isatty(),
        cluster=args.cluster,
        identify=not args.no_identify,
        replay=not args.no_replay,
        cases_file=args.cases,
    )


if __name__ == "__main__":
    raise SystemExit(main())
