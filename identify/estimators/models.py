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
        return np.stack(
            [
                p[:, 0] + p[:, 1] * a + (1.0 + p[:, 2]) * q + p[:, 3] * de,
                p[:, 4] + p[:, 5] * a + p[:, 6] * q + p[:, 7] * de,
            ],
            axis=1,
        )

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
#: The short-period states: airspeed, pitch attitude and thrust held at the record's values.
SHORT_PERIOD_STATES = ("alpha_rad", "q_rps")
SHORT_PERIOD_OUTPUTS = ("alpha_rad", "q_rps", "qdot_rps2")


def longitudinal(  # noqa: C901
    airframe: Airframe,
    terms: Mapping[str, Sequence[str]],
    inputs: Sequence[str] = ("de_rad",),
    offsets: Mapping[str, float] | None = None,
    outputs: Sequence[str] = LONGITUDINAL_OUTPUTS,
    states: Sequence[str] = LONGITUDINAL_STATES,
) -> StateSpaceModel:
    """Rigid-body longitudinal equations in the stability axes, coefficients linear in regressors.

    States V, alpha, theta, q; outputs those and qdot, ax, az (body accelerations at the CG,
    gravity excluded). ``CD``, ``CL``, ``Cm`` are each a sum of ``C<coef><regressor>`` times
    a regressor. Regressors: ``1``, ``V`` (``V/V0``), ``alpha`` (``alpha - offsets['alpha_rad']``),
    ``alpha2`` (its square), ``qhat`` (``q cbar/(2 V0)``), ``qhat_v`` (``q cbar/(2 V)``), ``mach`` (``V/a - offsets['mach']``,
    needing an input ``a``), and any input by name minus its offset. The last inputs are
    ``thrust`` [N or lbf] and ``rho`` [kg/m^3 or slug/ft^3] when present, else the density is
    ``offsets['rho']``.

    With ``states`` :data:`SHORT_PERIOD_STATES` the model is the short period written in the
    same coefficients: airspeed held at ``V0``, the flight-path angle at ``offsets['gamma_rad']``
    and the thrust's normal component at its value at ``offsets['alpha_rad']``, so that
    ``alpha' = q + (g cos(gamma0) - T sin(alpha0 + thrust angle) / m - qbar S CL) / V0`` and
    ``q' = (qbar S cbar Cm + thrust arm T) / Iy`` are linear in alpha, q and the inputs: the
    dimensional derivatives are ``Z_x = -qbar S CL_x / (m V0)`` and ``M_x = qbar S cbar Cm_x / Iy``
    (``x`` alpha or an input; for ``qhat`` times ``cbar / (2 V0)``). It has no drag: ``CD``
    takes no terms, and its outputs are alpha, q and qdot.

    Parameters
    ----------
    terms : mapping
        ``{"CD": [...], "CL": [...], "Cm": [...]}``: the regressors of each coefficient.
    inputs : sequence of str
        The record's input columns, in order.
    offsets : mapping, optional
        Reference values the regressors are taken about.
    outputs : sequence of str
        A selection of :data:`LONGITUDINAL_OUTPUTS` (:data:`SHORT_PERIOD_OUTPUTS`), in the
        record's order.
    states : sequence of str
        :data:`LONGITUDINAL_STATES` or :data:`SHORT_PERIOD_STATES`.

    Returns
    -------
    StateSpaceModel
        Parameters named ``CD0``, ``CDV``, ``CDalpha``, ... (``0`` for the constant).
    """
    off = dict(offsets or {})
    inputs, outputs, states = tuple(inputs), tuple(outputs), tuple(states)
    short = states == SHORT_PERIOD_STATES
    if not short and states != LONGITUDINAL_STATES:
        raise ValueError(f"states must be {LONGITUDINAL_STATES} or {SHORT_PERIOD_STATES}, not {states}")
    allowed = SHORT_PERIOD_OUTPUTS if short else LONGITUDINAL_OUTPUTS
    unknown = set(outputs) - set(allowed)
    if unknown:
        raise ValueError(f"unknown outputs {sorted(unknown)}; the model has {allowed}")
    if short and terms.get("CD"):
        raise ValueError("the short-period model has no drag: CD takes no terms")
    names, slices, start = [], {}, 0
    used: list[str] = []
    for coef in ("CD", "CL", "Cm"):
        regs = tuple(terms.get(coef, ()))
        names += [coef + ("0" if r == "1" else r) for r in regs]
        used += [r for r in regs if r not in used]
        slices[coef] = (slice(start, start + len(regs)), np.array([used.index(r) for r in regs], dtype=int))
        start += len(regs)
    it = inputs.index("thrust") if "thrust" in inputs else None
    ir = inputs.index("rho") if "rho" in inputs else None
    ia = inputs.index("a") if "a" in inputs else None
    af = airframe
    a_ref, mach_ref = off.get("alpha_rad", 0.0), off.get("mach", 0.0)
    by_input = {r: (inputs.index(r), off.get(r, 0.0)) for r in used if r in inputs}
    unknown = set(used) - set(by_input) - {"1", "V", "alpha", "alpha2", "qhat", "qhat_v", "mach"}
    if unknown:
        raise ValueError(f"unknown regressors {sorted(unknown)}: neither a model variable nor an input")

    def regressors(v, a, q, u):
        out = np.empty((len(a), len(used)))
        for j, name in enumerate(used):
            if name == "1":
                out[:, j] = 1.0
            elif name == "V":
                out[:, j] = v / af.v0
            elif name == "alpha":
                out[:, j] = a - a_ref
            elif name == "alpha2":
                out[:, j] = (a - a_ref) ** 2
            elif name == "qhat":
                out[:, j] = q * (af.chord / (2.0 * af.v0))
            elif name == "qhat_v":
                out[:, j] = q * af.chord / (2.0 * v)
            elif name == "mach":
                out[:, j] = v / u[ia] - mach_ref
            else:
                k, o = by_input[name]
                out[:, j] = u[k] - o
        return out

    kept = {}  # the parameters of the last call, spread over (coefficient, regressor): one batch's are reused

    def weights(p):
        key = (p.shape, p.tobytes())
        if kept.get("key") != key:
            w = np.zeros((len(p), 3, len(used)))
            for k, (sl, ix) in enumerate(slices.values()):
                w[:, k, ix] = p[:, sl]
            kept.update(key=key, w=w)
        return kept["w"]

    def coefficients(v, a, q, u, p):
        c = np.einsum("bkr,br->kb", weights(p), regressors(v, a, q, u))
        return {"CD": c[0], "CL": c[1], "Cm": c[2]}

    def state(x):
        if short:
            return af.v0, x[:, 0], None, x[:, 1]
        return x[:, 0], x[:, 1], x[:, 2], x[:, 3]

    def forces(x, u, p):
        v, a, th, q = state(x)
        rho = u[ir] if ir is not None else off["rho"]
        qs = 0.5 * rho * v**2 * af.area
        return v, a, th, q, qs, coefficients(v, a, q, u, p), (u[it] if it is not None else 0.0)

    def f(x, u, p):
        v, a, th, q, qs, c, thrust = forces(x, u, p)
        m = af.mass
        out = np.empty_like(x)
        out[:, -1] = (qs * af.chord * c["Cm"] + af.thrust_arm * thrust) / af.iyy
        if short:
            out[:, 0] = (
                q
                + (
                    af.g * np.cos(off.get("gamma_rad", 0.0))
                    - thrust * np.sin(a_ref + af.thrust_angle_rad) / m
                    - qs * c["CL"] / m
                )
                / v
            )
            return out
        ath = a - th
        out[:, 0] = (-qs * c["CD"] + thrust * np.cos(a + af.thrust_angle_rad)) / m + af.g * np.sin(ath)
        out[:, 1] = (-qs * c["CL"] - thrust * np.sin(a + af.thrust_angle_rad)) / (m * v) + q + af.g * np.cos(ath) / v
        out[:, 2] = q
        return out

    def g(x, u, p):
        v, a, th, q, qs, c, thrust = forces(x, u, p)
        qdot = (qs * af.chord * c["Cm"] + af.thrust_arm * thrust) / af.iyy
        full = {"alpha_rad": a, "q_rps": q, "qdot_rps2": qdot}
        if not short:
            sa, ca = np.sin(a), np.cos(a)
            full.update(
                V=v,
                theta_rad=th,
                ax=(qs * (c["CL"] * sa - c["CD"] * ca) + thrust * np.cos(af.thrust_angle_rad)) / af.mass,
                az=(qs * (-c["CL"] * ca - c["CD"] * sa) - thrust * np.sin(af.thrust_angle_rad)) / af.mass,
            )
        return np.stack([full[k] for k in outputs], axis=1)

    return StateSpaceModel(f, g, states, inputs, outputs, tuple(names))
