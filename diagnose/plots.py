"""Diagnosis plots. Each takes ``ax=``/``axes=`` and returns the figure.

Fixed margins rather than a layout engine: the diagnosis draws a hundred of these, and
constrained layout took half of their time."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from matplotlib.figure import Figure

from diagnose.residuals import COEFFS
from diagnose.result import Diagnosis
from identify.figures import emptied_axes, new_figure

LABEL = {"CL": "$C_L$", "CD": "$C_D$", "Cm": "$C_m$ (about AERORP)"}
RESPONSE_CHANNELS = (
    ("theta_deg", "pitch [deg]"),
    ("alpha_deg", "alpha [deg]"),
    ("q_dps", "q [deg/s]"),
    ("tas_kt", "TAS [kt]"),
    ("alt_ft", "altitude [ft]"),
)
RESPONSE_SIZE, HISTORY_SIZE, RESIDUALS_SIZE = (10, 11), (10, 7), (15, 4.5)  # [in]


def residuals_axes(fig):
    """The axes of :func:`plot_residuals` on ``fig``."""
    axes = fig.subplots(1, 3)
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.12, top=0.9, wspace=0.28)
    return axes


def response_axes(fig):
    """The axes of :func:`plot_response` on ``fig``."""
    axes = fig.subplots(len(RESPONSE_CHANNELS), 1, sharex=True)
    fig.subplots_adjust(left=0.1, right=0.98, bottom=0.05, top=0.95, hspace=0.12)
    return axes


def history_axes(fig):
    """The axes of :func:`plot_residual_history` on ``fig``."""
    axes = fig.subplots(3, 1, sharex=True)
    fig.subplots_adjust(left=0.12, right=0.98, bottom=0.08, top=0.93, hspace=0.12)
    return axes


def plot_residuals(diag: Diagnosis, axes=None):
    """Residual of each coefficient against the variable of its first cause, with the fit.

    Parameters
    ----------
    diag : Diagnosis
        The diagnosis (:func:`diagnose.diagnosis.diagnose`).
    axes : array of 3 Axes, optional
        Where to draw (CL, CD, Cm); a new pyplot figure of :data:`RESIDUALS_SIZE` if None.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if axes is None:
        axes = residuals_axes(new_figure(RESIDUALS_SIZE))
    d = diag.data
    first = {}
    for cause in diag.causes:
        if cause.kind == "aero":  # an instrument error's "variable" is its channel, not a residual column
            first.setdefault(cause.coefficient, cause)
    for ax, c in zip(axes, COEFFS):
        cause = first.get(c)
        var = cause.variables[0] if cause else "gear_norm"
        ax.plot(d[var], d[f"r_{c}"], ".", ms=1, color="0.6", label="measured - model")
        if cause:
            ax.plot(cause.curve[var], cause.curve[f"d{c}"], "r-", lw=2, label=f"identified: {cause.shape}")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_xlabel(var)
        ax.set_ylabel(f"residual {LABEL[c]}")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].figure.suptitle("Coefficient residuals: measured (eq. 1) minus the model at the measured states")
    return axes[0].figure


def plot_response(
    data: pd.DataFrame,
    before: pd.DataFrame,
    after: pd.DataFrame | None,
    title: str,
    axes=None,
    band: dict | None = None,
):
    """Measured response against the model (and the extended model), same inputs and start.

    Parameters
    ----------
    data, before : DataFrame
        The measured log and the model's replay of it (``t_s`` [s] and the channels of
        :data:`RESPONSE_CHANNELS`, units in their names).
    after : DataFrame or None
        The extended model's replay.
    title : str
    axes : array of 5 Axes, optional
        Where to draw (:func:`response_axes`); a new pyplot figure of :data:`RESPONSE_SIZE` if None.
    band : dict, optional
        Channel -> (t_s, lo, hi): the extended model's Monte Carlo band, shaded.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if axes is None:
        axes = response_axes(new_figure(RESPONSE_SIZE))
    for ax, (ch, label) in zip(axes, RESPONSE_CHANNELS):
        if band and ch in band:
            t, lo, hi = band[ch]
            ax.fill_between(t, lo, hi, color="tab:blue", alpha=0.2, lw=0, label="extended model, 95 % band")
        ax.plot(data.t_s, data[ch], color="0.3", lw=3, alpha=0.4, label="measured")
        ax.plot(before.t_s, before[ch], "r--", lw=1.2, label="model")
        if after is not None:
            ax.plot(after.t_s, after[ch], "b-", lw=1.0, label="extended model")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=9)
    axes[-1].set_xlabel("time [s]")
    axes[0].figure.suptitle(title)
    return axes[0].figure


def plot_residual_history(log_frame: pd.DataFrame, after: pd.DataFrame | None, title: str, axes=None):
    """Residual time histories of a held-out log, before and after the extension.

    Parameters
    ----------
    log_frame : DataFrame
        The model's residual data of the log (``t_s`` [s], ``r_CL``, ``r_CD``, ``r_Cm`` [-]).
    after : DataFrame or None
        The extended model's residual data of the same log.
    title : str
    axes : array of 3 Axes, optional
        Where to draw (:func:`history_axes`); a new pyplot figure of :data:`HISTORY_SIZE` if None.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if axes is None:
        axes = history_axes(new_figure(HISTORY_SIZE))
    for ax, c in zip(axes, COEFFS):
        ax.plot(log_frame.t_s, log_frame[f"r_{c}"], "r-", lw=1, label="model")
        if after is not None:
            ax.plot(after.t_s, after[f"r_{c}"], "b-", lw=1, label="extended model")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylabel(f"residual {LABEL[c]}")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=9)
    axes[-1].set_xlabel("time [s]")
    axes[0].figure.suptitle(title)
    return axes[0].figure


def save_overview(diag: Diagnosis, folder: Path) -> None:
    """``residuals_vs_cause.png`` in ``folder``: the residuals of each coefficient against its first
    cause's variable."""
    fig = plot_residuals(diag, axes=residuals_axes(Figure(figsize=RESIDUALS_SIZE)))
    fig.savefig(folder / "residuals_vs_cause.png", dpi=100)


def save_log_plots(
    name: str,
    data: pd.DataFrame,
    before: pd.DataFrame,
    after: pd.DataFrame | None,
    flown_before: pd.DataFrame | None,
    flown_after: pd.DataFrame | None,
    folder: Path,
    band: dict | None = None,
) -> None:
    """A held-out log's residual history (``residuals_<name>.png``) and, if it was replayed, its
    response (``response_<name>.png``), in ``folder``; one figure of each kind is reused per process."""
    fig = plot_residual_history(
        before, after, f"held out: {name}", axes=emptied_axes("residual_history", HISTORY_SIZE, history_axes)
    )
    fig.savefig(folder / f"residuals_{name}.png", dpi=90)
    if flown_before is not None:
        fig = plot_response(
            data,
            flown_before,
            flown_after,
            f"held out: {name}, same start and inputs",
            axes=emptied_axes("response", RESPONSE_SIZE, response_axes),
            band=band,
        )
        fig.savefig(folder / f"response_{name}.png", dpi=90)
