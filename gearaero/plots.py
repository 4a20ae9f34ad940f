"""Plots. Each takes ``ax=`` or ``axes=`` (a new pyplot figure of the caller's backend if not
given), returns the figure, and never chooses a matplotlib backend."""

from __future__ import annotations

from pathlib import Path

from diagnose.plots import plot_residual_history, plot_residuals, plot_response
from identify.plots import plot_alpha_transitions, plot_fit, plot_increments

__all__ = [
    "plot_fit",
    "plot_increments",
    "plot_alpha_transitions",
    "plot_residuals",
    "plot_response",
    "plot_residual_history",
    "plot_replay",
]


def plot_replay(campaign, case: str, loop: str = "open", axes=None):
    """A replay case's time histories and errors on the reference and the identified models, with
    the Part 60 tolerance bands (the report's figure), from a campaign's stored replays.

    Parameters
    ----------
    campaign : str, Path or CampaignResult
        A campaign folder with replays.
    case : str
        The case's name (``"landing-135kt"``, ``"takeoff-145kt"``...).
    loop : {"open", "closed"}
        Controls frozen, or the altitude and speed hold engaged.
    axes : array of 5x2 Axes, optional
        Where to draw (pitch [deg], alpha [deg], q [deg/s], TAS [kt], altitude [ft]; history and
        error); a new pyplot figure if None.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from campaign.errors import UserError
    from campaign.replays.report import load_bands, load_replays, plot_case

    folder = Path(getattr(campaign, "folder", campaign))
    replays = {k: v for k, v in load_replays(folder, [case]).items() if k[0] == case and k[2] == loop}
    if (case, "reference", loop) not in replays:
        raise UserError(f"{folder / 'replays'}: no replay of case {case!r}, {loop} loop")
    bands = {k: v for k, v in load_bands(folder)[1].items() if k[0] == case and k[2] == loop}
    return plot_case(replays, case, loop, axes=axes, bands=bands)
