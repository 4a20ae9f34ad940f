"""Figures a process draws many of, made once and emptied between uses.

matplotlib builds a figure's axes and their ticks slowly: a report figure redrawn on the
emptied axes of the last one costs half of a new one, and gives the same pixels."""

from __future__ import annotations

from typing import Callable

import numpy as np
from matplotlib.figure import Figure

_made: dict = {}  # (name, figsize) -> axes, in this process


def new_figure(figsize: tuple[float, float]):
    """A new pyplot figure, for a plotting function called without ``ax=``: it belongs to the
    caller's backend (a notebook's inline one, a window, Agg where there is no display), which
    this package never chooses. The files the package writes are drawn on figures of their own
    (:func:`emptied_axes`, ``matplotlib.figure.Figure``), outside pyplot.

    Parameters
    ----------
    figsize : tuple of float
        Width and height [in].
    """
    import matplotlib.pyplot as plt

    return plt.figure(figsize=figsize)


def emptied_axes(name: str, figsize: tuple[float, float], layout: Callable[[Figure], np.ndarray]) -> np.ndarray:
    """This process's axes for figure ``name``, without the artists of their last use.

    Parameters
    ----------
    name : str
        Which figure (one per plotting function).
    figsize : tuple of float
        Width and height [in].
    layout : callable
        Makes the axes on a new ``Figure`` (the same call as the plotting function's own).

    Returns
    -------
    ndarray of Axes
        Their lines, patches, collections, texts and legends removed and their limits reset;
        labels and titles are left for the plotting function to set again.
    """
    key = (name, tuple(figsize))
    if key not in _made:
        _made[key] = np.asarray(layout(Figure(figsize=figsize)))
        return _made[key]
    axes = _made[key]
    for ax in axes.ravel():
        for artist in [*ax.lines, *ax.patches, *ax.collections, *ax.texts]:
            artist.remove()
        if ax.get_legend() is not None:
            ax.get_legend().remove()
        ax.relim()
        ax.autoscale()
    return axes
