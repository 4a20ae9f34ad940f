"""Identification plots (paper Figs. 6-9, 11, 12). Each takes ``ax=`` and returns the figure.

Fixed margins rather than a layout engine: constrained layout took half of their time."""

from __future__ import annotations

import matplotlib
import numpy as np
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize

from identify.figures import new_figure
from identify.models import COEFFS, Increments, PointFit

LABEL = {"CL": "$C_L$", "CD": "$C_D$", "Cm": "$C_m$"}
FIT_SIZE, ALPHA_SIZE, INCREMENTS_SIZE = (12, 8), (8, 5), (15, 4.5)  # [in]


def fit_axes(fig):
    """The axes of :func:`plot_fit` on ``fig``."""
    axes = fig.subplots(3, 2, sharex=True)
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.07, top=0.91, wspace=0.25, hspace=0.3)
    return axes


def alpha_axes(fig):
    """The axes of :func:`plot_alpha_transitions` on ``fig``."""
    ax = fig.subplots()
    fig.subplots_adjust(left=0.1, right=0.97, bottom=0.12, top=0.92)
    return ax


def increments_axes(fig):
    """The axes of :func:`plot_increments` on ``fig``."""
    axes = fig.subplots(1, 3)
    fig.subplots_adjust(left=0.06, right=0.94, bottom=0.13, top=0.88, wspace=0.3)
    return axes


def plot_fit(fit: PointFit, t_s: np.ndarray, axes=None):
    """Measured vs fitted coefficients and residuals of one 2-3-1-1 (Figs. 6-9).

    Parameters
    ----------
    fit : PointFit
        A per-point fit that kept its series (``identify_logs(..., series=...)``).
    t_s : ndarray
        Time of the samples [s].
    axes : array of 3x2 Axes, optional
        Where to draw (:func:`fit_axes`); a new pyplot figure of :data:`FIT_SIZE` if None.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if axes is None:
        axes = fit_axes(new_figure(FIT_SIZE))
    fig = axes[0][0].figure
    for i, c in enumerate(COEFFS):
        res = fit.fits[c]
        ax, axr = axes[i][0], axes[i][1]
        ax.plot(t_s, res.fitted, "b-", lw=2.5, alpha=0.6, label="identified model (eq. 3)")
        ax.plot(t_s, res.y, "r.", ms=1.0, zorder=3, label="flight data (eq. 1)")
        ax.set_ylabel(LABEL[c])
        axr.plot(t_s, res.resid, "k-", lw=0.8)
        axr.axhline(0, color="0.6", lw=0.5)
        axr.set_ylabel(f"residual {LABEL[c]}")
        axr.set_title(f"max {res.resid_max:.2g}, RMS {res.resid_rms:.2g}, $R^2$ {res.rsquared:.4f}", fontsize=9)
    axes[0][0].legend(fontsize=8)
    axes[-1][0].set_xlabel("time [s]")
    axes[-1][1].set_xlabel("time [s]")
    fig.suptitle(f"{fit.point}: {'gear down' if fit.gear_down else 'gear up'}")
    return fig


def plot_alpha_transitions(incs: list[Increments], ax=None):
    """Angle of attack against normalized gear position during the transitions (Fig. 11).

    Parameters
    ----------
    incs : list of Increments
        The gear increments of each transition (``Identification.increments``).
    ax : Axes, optional
        Where to draw; a new pyplot figure of :data:`ALPHA_SIZE` if None.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if ax is None:
        ax = alpha_axes(new_figure(ALPHA_SIZE))
    cmap = matplotlib.colormaps["viridis"]
    trims = np.array([i.alpha_trim_deg for i in incs])
    lo, hi = trims.min(), max(trims.max(), trims.min() + 1e-9)
    for inc in incs:
        moving = (inc.gear_norm > 0.0) & (inc.gear_norm < 1.0)
        ax.plot(
            inc.gear_norm[moving],
            inc.alpha_deg[moving] - inc.alpha_trim_deg,
            lw=0.8,
            color=cmap((inc.alpha_trim_deg - lo) / (hi - lo)),
        )
    ax.figure.colorbar(ScalarMappable(cmap=cmap, norm=Normalize(lo, hi)), ax=ax, label=r"trim $\alpha$ [deg]")
    ax.set_xlabel(r"normalized gear position $\delta_{LG}$ [-]")
    ax.set_ylabel(r"$\alpha - \alpha_{trim}$ [deg]")
    ax.set_title(f"Angle of attack during gear transitions ({len(incs)} status points)")
    ax.grid(alpha=0.3)
    return ax.figure


def plot_increments(incs: list[Increments], axes=None):
    """Gear increments of CL, CD, Cm against delta_LG at each point (Fig. 12).

    Parameters
    ----------
    incs : list of Increments
        The gear increments of each transition (``Identification.increments``).
    axes : array of 3 Axes, optional
        Where to draw (CL, CD, Cm); a new pyplot figure of :data:`INCREMENTS_SIZE` if None.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if axes is None:
        axes = increments_axes(new_figure(INCREMENTS_SIZE))
    cmap = matplotlib.colormaps["viridis"]
    alphas = np.array([i.alpha_trim_deg for i in incs])
    lo, hi = (alphas.min(), alphas.max()) if len(alphas) else (0, 1)
    for inc in incs:
        color = cmap((inc.alpha_trim_deg - lo) / max(hi - lo, 1e-9))
        for ax, c in zip(axes, COEFFS):
            ax.plot(inc.grid, inc.smooth[c], color=color, lw=1.0)
    for ax, c in zip(axes, COEFFS):
        ax.set_xlabel(r"$\delta_{LG}$ [-]")
        ax.set_ylabel(rf"$\Delta${LABEL[c]}")
        ax.grid(alpha=0.3)
    sm = ScalarMappable(cmap=cmap, norm=Normalize(lo, hi))
    axes[-1].figure.colorbar(sm, ax=list(axes), label=r"trim $\alpha$ [deg]", fraction=0.02, pad=0.02)
    axes[0].figure.suptitle("Gear increments (eq. 8), one curve per status point")
    return axes[0].figure
