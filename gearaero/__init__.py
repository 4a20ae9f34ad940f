"""gearaero: fly a JSBSim flight-test campaign, identify landing-gear aerodynamics from the logs, and
find what a simulation model gets wrong.

From logs to a diagnosis::

    import gearaero as ga

    camp = ga.fly(matrix="small.toml", out="results/small", jobs=2, noise="flight-test")
    print(camp.summary())                    # points flown, identification, Part 60 replay table
    ident = ga.identify(camp, method="oe")   # eq. (3) by output error this time
    print(ident.linear_gear_model)           # dCL_gear, dCD_gear, dCm_gear per condition

    diag = ga.diagnose(camp, model=ga.SHIPPED_737, out="results/small-diagnosis", jobs=2)
    print(diag.verdict)                      # "discrepancy" or "no significant discrepancy"
    # the same with another threshold: every decision's is a field of ga.DiagnosisSettings
    strict = ga.DiagnosisSettings(replicate_gain=1.5)
    ga.diagnose(camp, model=ga.SHIPPED_737, out="results/strict-diagnosis", settings=strict)
    print(diag.summary())                    # the causes, their evidence and the gain
    if diag.unsettled:                       # rival explanations the data cannot tell apart
        flights = ga.plan(diag, budget_min=10)   # the flights that would, within 10 minutes
        print(flights.summary())
    print(ga.report(camp).summary())         # report.html: Part 60 results first

    logs = ga.read_logs("measured/")         # or from pandas:
    log = ga.log_from_frame(df, S_ft2=1341.0, cbar_ft=12.98, iyy_slugft2=2.48e6, mass_slug=4196.0)

Every job returns a results object with ``summary()`` (text) and ``to_dict()`` (JSON-ready);
each is the ``campaign`` command of the same name. The plotting functions take ``ax=`` (or
``axes=``), return the figure and never choose a matplotlib backend. Workers never import your
``__main__``: a script needs no ``if __name__ == "__main__"`` guard, and ``python -`` and a
Jupyter kernel work as well (on Linux and macOS; on Windows, guard the script).

Units are in the names (``alpha_deg``, ``q_dps``, ``thrust_lbf``); JSBSim property names are
verbatim.
"""

from __future__ import annotations

from aircraft import SHIPPED_737
from campaign.errors import UserError
from diagnose.config import DiagnosisSettings
from gearaero.jobs import diagnose, fly, identify, model, plan, report
from gearaero.logs import FRAME_COLUMNS, log_from_frame, read_logs, write_logs
from gearaero.plots import (
    plot_alpha_transitions,
    plot_fit,
    plot_increments,
    plot_replay,
    plot_residual_history,
    plot_residuals,
    plot_response,
)
from gearaero.results import (
    CampaignResult,
    DiagnosisResult,
    IdentificationResult,
    ModelResult,
    PlanResult,
    ReportResult,
)
from identify.compat import CompatSettings
from identify.logs import Log, LogError
from infra.provenance import version as _version

#: The installed version (single-sourced in ``pyproject.toml``).
__version__ = _version()

__all__ = [  # noqa: RUF022 (grouped as the API reads: help() shows the start of it)
    "__version__",
    "SHIPPED_737",
    "UserError",
    "LogError",
    "Log",
    "FRAME_COLUMNS",
    "DiagnosisSettings",
    "CompatSettings",
    "read_logs",
    "log_from_frame",
    "write_logs",
    "fly",
    "identify",
    "model",
    "diagnose",
    "plan",
    "report",
    "CampaignResult",
    "IdentificationResult",
    "ModelResult",
    "DiagnosisResult",
    "PlanResult",
    "ReportResult",
    "plot_fit",
    "plot_increments",
    "plot_alpha_transitions",
    "plot_residuals",
    "plot_response",
    "plot_residual_history",
    "plot_replay",
]
