"""Dryden turbulence of MIL-F-8785C with a chosen vertical gust intensity.

JSBSim's Milspec model (``atmosphere/turb-type`` 3) takes its intensity above
2000 ft from the seven curves of the specification's probability-of-exceedance
table (``atmosphere/turbulence/milspec/severity``): 2.1 ft/s RMS vertical gust
at 2000 ft for the lightest, and nothing at all above 7500 ft. No property sets
any other intensity. This module runs the same discrete filters FGWinds runs
(MIL-STD-1797A as cited by Yeager 1998, eqs. 30-32, with the specification's
scale lengths) at the intensity asked for, and the engine feeds the gusts to
JSBSim through ``atmosphere/gust-north/east/down-fps``. JSBSim has no input for
the rotational gust terms of its own generator (p, q, r from the gust
gradients); they are left out.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter


def scales(h_ft: float, sigma_w_fps: float) -> tuple[float, float, float]:
    """Scale lengths L_u, L_w [ft] and longitudinal intensity sigma_u [ft/s] at an altitude.

    Above 2000 ft MIL-F-8785C takes L = 1750 ft and sigma_u = sigma_w; below 1000 ft
    its low-altitude forms (Figs. 10-11); in between, linear blending, as FGWinds does.
    """
    h = max(h_ft, 10.0)
    if h >= 2000.0:
        return 1750.0, 1750.0, sigma_w_fps
    low_lu = h / (0.177 + 0.000823 * h) ** 1.2
    low_su = sigma_w_fps / (0.177 + 0.000823 * h) ** 0.4
    if h <= 1000.0:
        return low_lu, h, low_su
    f = (h - 1000.0) / 1000.0
    length = 1000.0 + f * 750.0
    return length, length, low_su + f * (sigma_w_fps - low_su)


def dryden_gusts(
    n: int, dt_s: float, v_fps: float, h_ft: float, sigma_w_fps: float, rng: np.random.Generator
) -> np.ndarray:
    """Longitudinal, lateral and vertical gust velocities [ft/s], ``n`` steps of ``dt_s``.

    First-order recursions ``x[k] = a x[k-1] + b nu[k]`` with ``a = 1 - c dt V / L``
    (c = 1 for u, 2 for v and w, as FGWinds), their input gain set so that the
    stationary RMS is exactly the intensity asked for; they start in their
    stationary state, so the gusts have their full intensity from the first step.

    Returns
    -------
    ndarray, shape (n, 3)
        u (along the wind axis, here north), v (east) and w (down) gusts.
    """
    out = np.zeros((n, 3))
    if sigma_w_fps <= 0.0 or n == 0:
        return out
    l_u, l_w, sig_u = scales(h_ft, sigma_w_fps)
    for j, (length, sigma, k) in enumerate(((l_u, sig_u, 1.0), (l_u, sig_u, 2.0), (l_w, sigma_w_fps, 2.0))):
        a = max(1.0 - k * dt_s * v_fps / length, 0.0)
        b = sigma * np.sqrt(1.0 - a * a)
        start = sigma * rng.standard_normal()
        out[:, j], _ = lfilter([b], [1.0, -a], rng.standard_normal(n), zi=[a * start])
    return out
