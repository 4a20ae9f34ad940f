"""What each job of :mod:`gearaero` returns: the files it wrote, read back, with ``summary()`` (text)
and ``to_dict()`` (JSON-ready)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd


def _json(path: Path) -> dict:
    return json.loads(Path(path).read_text())


def _csv(path: Path) -> pd.DataFrame:
    """The table, or an empty one where the identification had nothing to write (no gear-down fit for a
    linear gear model)."""
    try:
        return pd.read_csv(path)
    except pd.errors.EmptyDataError:
        return pd.DataFrame()


@dataclass
class IdentificationResult:
    """An identification: eq. (1) coefficients, eq. (3) fits per point, the gear models (eqs. 4, 8, 9)
    and their JSBSim XML.

    Attributes
    ----------
    folder : Path
        Where it was written (``identification.json``, ``summary.txt``, CSV tables, ``gear_*.xml``,
        ``aircraft_*`` folders with the gear models merged, ``plots/``).
    files : dict of str to str
        What was written, by kind (``json``, ``summary``, ``xml_linear``, ``xml_nonlinear``,
        ``aircraft_nonlinear``, ``plot_...``).
    identification : identify.pipeline.Identification or None
        The results in memory (per-point fits with ``params``, standard errors and ``summary()``,
        the linear gear models, the increments, the eq. (9) surfaces) when computed by this call;
        None when a stored identification was kept.
    kept : bool
        True if the folder's identification was made from the same logs, model and options
        already, and kept.
    """

    folder: Path
    files: dict = field(default_factory=dict)
    identification: object | None = None
    kept: bool = False

    def to_dict(self) -> dict:
        """``identification.json``: the tool, the method, each point's fits (``params``, ``bse``, R^2,
        residuals), the linear gear models, the increments, the surfaces, notes and files."""
        return _json(self.folder / "identification.json")

    @property
    def parameters(self) -> pd.DataFrame:
        """Every point's eq. (3) parameters: ``point``, ``gear``, ``coefficient``, ``parameter``,
        ``estimate``, ``std_error``, ``identifiable``, ``note``, ``method`` (the estimator the number came
        from; regressors in rad, [1/rad])."""
        return _csv(self.folder / "baseline_parameters.csv")

    @property
    def linear_gear_model(self) -> pd.DataFrame:
        """The linear gear model (eq. 4) per condition: gear-up and gear-down C0, ``dCL_gear``,
        ``dCD_gear``, ``dCm_gear`` [-] and the derivatives; empty where no condition was fitted both gear up
        and gear down."""
        return _csv(self.folder / "linear_gear_model.csv")

    @property
    def not_converged(self) -> list[dict]:
        """The points whose output-error or filter-error fit did not converge: ``point``, ``method``,
        ``reason`` (their estimates are the equation error's, labelled ``ee``); empty for equation error."""
        return list(self.to_dict().get("not_converged", []))

    def summary(self) -> str:
        """The identification's summary: gear increments, eq. (9) designs, the data compatibility
        (``summary.txt`` without its per-point fits), and where the files are."""
        text = (self.folder / "summary.txt").read_text()
        head = text.split("\nPer-point fits\n", 1)[0].rstrip()
        kept = " (kept: made from these logs and options already)" if self.kept else ""
        return f"{head}\n\nFiles in {self.folder}{kept}; per-point fits in summary.txt.\n"


@dataclass
class CampaignResult:
    """A campaign flown (``campaign run``): logs, manifest, identification, replays and report.

    Attributes
    ----------
    folder : Path
        The campaign folder.
    status : int
        0, or 1 if no point flew or a replay failed (the command's exit code).
    messages : list of str
        What the run said, in order (``campaign run`` prints the same lines).
    """

    folder: Path
    status: int = 0
    messages: list = field(default_factory=list)

    @property
    def manifest(self) -> dict:
        """``manifest.json``: the tool, settings and hashes, the matrix, seeds, each point's status."""
        return _json(self.folder / "manifest.json")

    @property
    def identification(self) -> IdentificationResult | None:
        """The campaign's identification, if it has one."""
        f = self.folder / "identification"
        return IdentificationResult(f) if (f / "identification.json").is_file() else None

    @property
    def metrics(self) -> pd.DataFrame | None:
        """The replays' Part 60 metrics (``replays/metrics.csv``: max and RMS errors per case, model and
        loop [deg, deg/s, kt, ft], ``qtg_pass``), or None without replays."""
        f = self.folder / "replays" / "metrics.csv"
        return pd.read_csv(f) if f.is_file() else None

    @property
    def report(self) -> Path | None:
        """``report.html``, if written."""
        f = self.folder / "report.html"
        return f if f.is_file() else None

    def to_dict(self) -> dict:
        """The campaign, the tool, its points (how many flew, which failed and why), the files."""
        man = self.manifest
        failed = {p["id"]: p["reason"] for p in man["points"] if p["status"] != "ok"}
        m = self.metrics
        return {
            "folder": str(self.folder),
            "campaign": man.get("campaign"),
            "tool": man.get("tool"),
            "status": self.status,
            "complete": man.get("complete"),
            "points": len(man["points"]),
            "points_ok": len(man["points"]) - len(failed),
            "failed": failed,
            "identification": str(self.folder / "identification") if self.identification else None,
            "replays": None if m is None else m.drop(columns=["tool"], errors="ignore").to_dict("records"),
            "report": str(self.report) if self.report else None,
        }

    def summary(self) -> str:
        """What the run said (points flown, identification, Part 60 replay table, report)."""
        return "\n".join(self.messages) + "\n" if self.messages else f"campaign in {self.folder}\n"


@dataclass
class DiagnosisResult:
    """A diagnosis (``campaign diagnose``): the verdict, the causes named with their evidence, the
    extension and its gain on held-out data.

    Attributes
    ----------
    folder : Path
        The diagnosis folder (``diagnosis.json``, ``diagnosis.txt``, ``extension.xml``,
        ``extended_aircraft/``, ``plots/``, ``report.html``).
    document : dict
        What ``diagnosis.json`` holds.
    """

    folder: Path
    document: dict

    @property
    def verdict(self) -> str:
        """``"discrepancy"``, ``"discrepancy, cause not confirmed"`` or ``"no significant discrepancy"``."""
        return self.document["verdict"]

    @property
    def causes(self) -> list[dict]:
        """The causes named, best first (kind, coefficient and variables or channel and error, shape,
        size, evidence, verdict)."""
        return self.document["causes"]

    @property
    def settings(self):
        """The :class:`diagnose.config.DiagnosisSettings` the diagnosis was made with (``diagnosis.json``
        records them)."""
        from diagnose.config import recorded

        return recorded(self.document)

    @property
    def unsettled(self) -> list[dict]:
        """The rival explanations these data do not reject (separation below the settled level of
        :attr:`settings`, in standard errors): what :func:`gearaero.plan` designs flights for."""
        settled_se = self.settings.settled_se
        return [r for r in self.document.get("rivals", []) if r["separation_se"] < settled_se]

    @property
    def extended_aircraft(self) -> Path | None:
        """The copy of the model with the extension merged, if a cause was named."""
        e = self.document.get("extension")
        return Path(e) if e else None

    def to_dict(self) -> dict:
        """``diagnosis.json``: the tool, the verdict, the causes, unconfirmed and rejected candidates with
        their evidence, the noise, the data compatibility, the rivals, the extension, the gain, the data."""
        return self.document

    def summary(self) -> str:
        """``diagnosis.txt``: the verdict, the causes, the data compatibility and the gain."""
        return self.document["summary"]


@dataclass
class PlanResult:
    """A flight plan (``campaign plan``): the flights that would best separate the rival explanations
    a diagnosis left open, within a budget of flight minutes.

    Attributes
    ----------
    folder : Path
        The plan folder (``plan.json``, ``plan.txt``, ``plan.toml``, ``candidates/``).
    document : dict
        What ``plan.json`` holds.
    """

    folder: Path
    document: dict

    @property
    def matrix(self) -> Path | None:
        """The chosen flights as a test-matrix TOML for :func:`gearaero.fly`, or None if none was chosen."""
        m = self.document.get("matrix")
        return Path(m) if m else None

    def to_dict(self) -> dict:
        """``plan.json``: the tool, the budget [min], each rival's separation now and planned [standard
        errors], the flights chosen [min] and the matrix."""
        return self.document

    def summary(self) -> str:
        """``plan.txt``: the rivals, the flights chosen and how to fly them."""
        return (self.folder / "plan.txt").read_text()


@dataclass
class ReportResult:
    """``report.html`` of a campaign or a diagnosis: one self-contained page.

    Attributes
    ----------
    path : Path
        The page.
    kind : str
        ``"campaign"`` or ``"diagnosis"``.
    first_page : list of dict
        What its summary opens with: for a campaign each Part 60 case and loop with its models'
        PASS/FAIL and smallest margin; for a diagnosis the verdict.
    """

    path: Path
    kind: str
    first_page: list = field(default_factory=list)

    def to_dict(self) -> dict:
        """``path``, ``kind`` and ``summary`` (the first page's rows; margins [%] of each tolerance)."""
        return {"path": str(self.path), "kind": self.kind, "summary": self.first_page}

    def summary(self) -> str:
        """The report's opening summary as text, and where the page is."""
        lines = [f"{self.kind} report: {self.path}"]
        for r in self.first_page:
            lines.append("  " + ", ".join(f"{k} {v}" for k, v in r.items()))
        return "\n".join(lines) + "\n"


@dataclass
class ModelResult:
    """A JSBSim aircraft written from an identification (``campaign model``).

    Attributes
    ----------
    folder : Path
        The aircraft folder: ``<name>.xml`` (load it with ``--model folder`` or as JSBSim aircraft
        ``name``) and ``model.json``.
    name : str
    lines : list of str
        What the command prints: what the aircraft is made of, how it interpolates, what is nominal,
        and its trim at the start of each identified record beside the logged values.
    """

    folder: Path
    name: str
    lines: list = field(default_factory=list)

    @property
    def xml(self) -> Path:
        """The aircraft file."""
        return self.folder / f"{self.name}.xml"

    def to_dict(self) -> dict:
        """``model.json``: the tool, the name, the identification it came from, the notes, and each
        trim (``alpha_deg``, ``elevator_deg``, ``stabilizer_deg`` [deg], ``thrust_lbf``, the logged
        values beside them, or the reason it failed)."""
        return _json(self.folder / "model.json")

    @property
    def trims(self) -> list[dict]:
        """The trim at the start of each identified record (:meth:`to_dict`'s ``trims``)."""
        return self.to_dict()["trims"]

    def summary(self) -> str:
        """What the command printed."""
        return "\n".join(self.lines) + "\n"
