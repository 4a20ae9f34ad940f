"""Small shared helpers for the tests and the benchmarks."""
from __future__ import annotations

import numpy as np


def _toml_value(v) -> str:
    return "[" + ", ".join(_toml_value(x) for x in v) + "]" if isinstance(v, (list, tuple)) else repr(v)


def matrix_toml(points, name: str = "test", header: str = "") -> str:
    """A test-matrix TOML from ``(gear, flap_deg, mach, alt_ft)`` rows (mach, alt_ft may be lists)."""
    rows = [f'[[points]]\ngear = "{g}"\nflap_deg = {f}\nmach = {_toml_value(m)}\nalt_ft = {_toml_value(a)}'
            for g, f, m, a in points]
    return f'name = "{name}"\n{header}' + "\n".join(rows) + "\n"


def pairs(*conditions) -> list[tuple]:
    """Each ``(flap_deg, mach, alt_ft)`` condition flown gear up and gear down."""
    return [(g, f, m, a) for f, m, a in conditions for g in ("up", "down")]


def z_scores(clean_fits, noisy_fits) -> np.ndarray:
    """|noisy - noise-free| / standard error, for every parameter both fits identified."""
    clean = {f.point: f for f in clean_fits}
    z = []
    for f in noisy_fits:
        for c, res in f.fits.items():
            ref = clean[f.point].fits[c]
            z += [(res.params[k] - ref.params[k]) / res.bse[k] for k in res.params.index if k in ref.params.index]
    return np.abs(np.array(z))
