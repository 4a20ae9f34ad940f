"""Model structures the estimators fit: a linear short period, and the longitudinal point
model of a rigid aeroplane with coefficients linear in named regressors."""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from identify.estimators.dynamics import StateSpaceModel

SHORT_PERIOD_PARAMS = ("Z0", "Zalpha", "Zq", "Zde", "M0", "Malpha", "Mq", "Mde")


def short_period() -> StateSpaceModel:
    """``alpha' = Z0 + Zalpha alpha + (1 + Zq) q + Zde de``, ``q' = M0 + Malpha alpha + Mq q + Mde de``.

    States and outputs alpha [rad] and q [rad/s], input de [rad]; parameters
    :data:`SHORT_PERIOD_PARAMS` (per second).
    """
    def f(x, u, p):
        a, q, de = x[:, 0], x[:, 1], u[0]
        return np.stack([p[:, 0] + p[:, 1] * a + (1.0 + p[:, 2]) * q + p[:, 3] * de,
                         p[:, 4] + p[:, 5] * a + p[:, 6] * q + p[:, 7] * de], axis=1)

    def g(x, u, p):
        return x.copy()

    return StateSpaceModel(f, g, ("alpha_rad", "q_rps"), ("de_rad",), ("alpha_rad", "q_rps"), SHORT_PERIOD_PARAMS)


@dataclass(frozen=True)
class Airframe:
    """Constants of the longitudinal point model, in one consistent unit system.

    Parameters
    ----------
    mass : float
        [kg] or [slug].
    area, chord : float
        Reference area and mean aerodynamic chord [m^2, m] or [ft^2, ft].
    iyy : float
        Pitch inertia [kg m^2] or [slug ft^2].
    v0 : float
        Reference speed for ``V/V0`` and ``qhat = q cbar / (2 V0)`` [m/s] or [ft/s].
    thrust_angle_rad : float
        Thrust line inclination to the body x axis [rad].
    thrust_arm : float
        Pitching moment of a unit thrust [m] or [ft] (positive nose up).
    g : float
        Gravity [m/s^2] or [ft/s^2].
    """

    mass: float
    area: float
    chord: float
    iyy: float
    v0: float
    thrust_angle_rad: float = 0.0
    thrust_arm: float = 0.0
    g: float = 9.80665


LONGITUDINAL_STATES = ("V", "alpha_rad", "theta_rad", "q_rps")
LONGITUDINAL_OUTPUTS = ("V", "alpha_rad", "theta_rad", "q_rps", "qdot_rps2", "ax", "az")


def longitudinal(airframe: Airframe, terms: Mapping[str, Sequence[str]], inputs: Sequence[str] = ("de_rad",),
                 offsets: Mapping[str, float] | None = None,
                 outputs: Sequence[str] = LONGITUDINAL_OUTPUTS) -> StateSpaceModel:
    """Rigid-body longitudinal equations in the stability axes, coefficients linear in regressors.

    States V, alpha, theta, q; outputs those and qdot, ax, az (body accelerations at the CG,
    gravity excluded). ``CD``, ``CL``, ``Cm`` are each a sum of ``C<coef><regressor>`` times
    a regressor. Regressors: ``1``, ``V`` (``V/V0``), ``alpha`` (``alpha - offsets['alpha_rad']``),
    ``alpha2`` (its square), ``qhat`` (``q cbar/(2 V0)``), ``qhat_v`` (``q cbar/(2 V)``), ``mach`` (``V/a - offsets['mach']``,
    needing an input ``a``), and any input by name minus its offset. The last inputs are
    ``thrust`` [N or lbf] and ``rho`` [kg/m^3 or slug/ft^3] when present, else the density is
    ``offsets['rho']``.

    Parameters
    ----------
    terms : mapping
        ``{"CD": [...], "CL": [...], "Cm": [...]}``: the regressors of each coefficient.
    inputs : sequence of str
        The record's input columns, in order.
    offsets : mapping, optional
        Reference values the regressors are taken about.
    outputs : sequence of str
        A selection of :data:`LONGITUDINAL_OUTPUTS`, in the record's order.

    Returns
    -------
    StateSpaceModel
        Parameters named ``CD0``, ``CDV``, ``CDalpha``, ... (``0`` for the constant).
    """
    off = dict(offsets or {})
    inputs = tuple(inputs)
    names, slices, start = [], {}, 0
    for coef in ("CD", "CL", "Cm"):
        regs = tuple(terms.get(coef, ()))
        names += [coef + ("0" if r == "1" else r) for r in regs]
        slices[coef] = (slice(start, start + len(regs)), regs)
        start += len(regs)
    it = inputs.index("thrust") if "thrust" in inputs else None
    ir = inputs.index("rho") if "rho" in inputs else None
    ia = inputs.index("a") if "a" in inputs else None
    af = airframe

    def regressor(name, x, u):
        v, a, q = x[:, 0], x[:, 1], x[:, 3]
        if name == "1":
            return np.ones_like(v)
        if name == "V":
            return v / af.v0
        if name == "alpha":
            return a - off.get("alpha_rad", 0.0)
        if name == "alpha2":
            return (a - off.get("alpha_rad", 0.0)) ** 2
        if name == "qhat":
            return q * af.chord / (2.0 * af.v0)
        if name == "qhat_v":
            return q * af.chord / (2.0 * v)
        if name == "mach":
            return v / u[ia] - off.get("mach", 0.0)
        return np.full_like(v, u[inputs.index(name)] - off.get(name, 0.0))

    def coefficients(x, u, p):
        out = {}
        for coef, (sl, regs) in slices.items():
            out[coef] = sum((p[:, sl][:, j] * regressor(r, x, u) for j, r in enumerate(regs)),
                            np.zeros(len(x)))
        return out

    def forces(x, u, p):
        v = x[:, 0]
        rho = u[ir] if ir is not None else off["rho"]
        qs = 0.5 * rho * v ** 2 * af.area
        c = coefficients(x, u, p)
        thrust = u[it] if it is not None else 0.0
        return qs, c, thrust

    def f(x, u, p):
        v, a, th, q = x.T
        qs, c, thrust = forces(x, u, p)
        m = af.mass
        vdot = (-qs * c["CD"] + thrust * np.cos(a + af.thrust_angle_rad)) / m + af.g * np.sin(a - th)
        adot = (-qs * c["CL"] - thrust * np.sin(a + af.thrust_angle_rad)) / (m * v) + q + af.g * np.cos(a - th) / v
        qdot = (qs * af.chord * c["Cm"] + af.thrust_arm * thrust) / af.iyy
        return np.stack([vdot, adot, q, qdot], axis=1)

    def g(x, u, p):
        v, a, th, q = x.T
        qs, c, thrust = forces(x, u, p)
        sa, ca = np.sin(a), np.cos(a)
        ax = (qs * (c["CL"] * sa - c["CD"] * ca) + thrust * np.cos(af.thrust_angle_rad)) / af.mass
        az = (qs * (-c["CL"] * ca - c["CD"] * sa) - thrust * np.sin(af.thrust_angle_rad)) / af.mass
        qdot = (qs * af.chord * c["Cm"] + af.thrust_arm * thrust) / af.iyy
        full = {"V": v, "alpha_rad": a, "theta_rad": th, "q_rps": q, "qdot_rps2": qdot, "ax": ax, "az": az}
        return np.stack([full[k] for k in outputs], axis=1)

    outputs = tuple(outputs)
    unknown = set(outputs) - set(LONGITUDINAL_OUTPUTS)
    if unknown:
        raise ValueError(f"unknown outputs {sorted(unknown)}; the model has {LONGITUDINAL_OUTPUTS}")
    return StateSpaceModel(f, g, LONGITUDINAL_STATES, inputs, outputs, tuple(names))
