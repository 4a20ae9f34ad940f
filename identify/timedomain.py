"""Eq. (3) point models by output error or filter error: ``campaign identify --method oe|fe``.

The equation-error fit of each excitation manoeuvre (:func:`identify.models.fit_baseline`) gives
the terms the record excited and the starting values. The same coefficients are then estimated
by integrating the rigid-body longitudinal equations (:func:`identify.estimators.models.longitudinal`)
against the measured time histories (:mod:`identify.estimators`), in the structure
:mod:`identify.structure` names: by default airspeed, alpha, pitch attitude and pitch rate, with
elevator, stabilizer and thrust as inputs, fitted to airspeed, alpha, attitude, pitch rate and the
two accelerations. The physics are eq. (1)'s: thrust along the body x axis on its documented line,
the aerodynamic moment about the CG, the log's mass and inertia. Records logged faster than 25 Hz
are low-passed as eq. (3)'s data are and resampled to about 10 Hz; slower ones are fitted as logged.

The manoeuvres of one status point (one condition, gear position and weight), repeats of one
input or several inputs, are fitted together: shared coefficients, each record its own initial
state (and, for output error, accelerometer biases).

A fit that does not converge is not reported as one: the point keeps its equation-error
estimates, labelled ``ee``, and :attr:`identify.models.PointFit.failure` says which method failed
and why.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import pandas as pd

from identify.coefficients import FT_PER_KT, coefficients
from identify.estimators import OutputError, Record
from identify.estimators.filtererror import FilterError
from identify.estimators.models import Airframe, longitudinal
from identify.kinematics import effective_gravity, pitch_acceleration
from identify.logs import Log
from identify.models import COEFFS, EDGE_S, PointFit, filtered_frame, lowpass, regressors, sample_interval
from identify.structure import DEFAULT, Structure

METHODS = ("ee", "oe", "fe")
NAMES = {"ee": "equation error", "oe": "output error", "fe": "filter error"}
RATE_HZ = 10.0
#: records logged up to this rate are fitted as logged; faster ones are low-passed and resampled to RATE_HZ [Hz]
MAX_RATE_HZ = 25.0
D2R = np.pi / 180.0
#: eq. (3) regressors as the longitudinal model names them
MODEL_REGRESSOR = {
    "const": "1",
    "dalpha_rad": "alpha",
    "qhat_rad": "qhat_v",
    "delevator_rad": "elevator_rad",
    "dstabilizer_rad": "stabilizer_rad",
    "dmach": "mach",
    "dalpha2_rad2": "alpha2",
}
#: log channel -> (model name, factor to the model's unit)
CHANNEL = {
    "tas_kt": ("V", FT_PER_KT),
    "alpha_deg": ("alpha_rad", D2R),
    "theta_deg": ("theta_rad", D2R),
    "q_dps": ("q_rps", D2R),
    "qdot_dps2": ("qdot_rps2", D2R),
    "ax_fps2": ("ax", 1.0),
    "az_fps2": ("az", 1.0),
    "elevator_deg": ("elevator_rad", D2R),
    "stabilizer_deg": ("stabilizer_rad", D2R),
    "thrust_lbf": ("thrust", 1.0),
}
#: starting process-noise standard deviations per state, as a share of the state's scatter over the record
#: (per sqrt(s)): the filter error's own start, refined with the parameters
F0_SHARE = 0.2
#: alpha's square enters a time-domain model when it varies this much apart from alpha (std) [deg^2]
MIN_CURVATURE_DEG2 = 1.0
#: the lift and drag terms the default structure keeps only where the time-domain and the equation-error
#: estimates agree within AGREE_SE combined standard errors (:func:`disagreement`)
SECONDARY = ("delevator_rad", "dstabilizer_rad", "dalpha2_rad2")
AGREE_SE = 3.0
#: outputs whose bias the output error estimates (the accelerometers: the data compatibility may leave one)
BIASED = ("ax", "az")


def param_name(coeff: str, term: str) -> str:
    """The model's name of a coefficient's term: ``CLalpha``, ``Cm0``, ..."""
    return f"{coeff}{'0' if term == 'const' else MODEL_REGRESSOR[term]}"


def _channel(d: pd.DataFrame, name: str) -> np.ndarray:
    if name == "qdot_dps2":
        return pitch_acceleration(d) * D2R
    _, k = CHANNEL[name]
    return d[name].to_numpy(dtype=float) * k


def _record(log: Log, structure: Structure) -> tuple[Record, dict]:
    """The record of one log in the model's units, low-passed and resampled, and its air data."""
    d = log.data
    dt = sample_interval(log)
    step = 1 if dt * MAX_RATE_HZ > 0.99 else max(1, int(round(1.0 / (RATE_HZ * dt))))
    chans = list(
        dict.fromkeys([*structure.outputs, *structure.states, *structure.inputs, "tas_kt", "alpha_deg", "theta_deg"])
    )
    raw = np.column_stack([_channel(d, c) for c in chans])
    # resampled, a record is low-passed first as eq. (3)'s are; at its own rate it is fitted as measured (the
    # estimators take the measurement noise as white, and a low-pass filter colours it)
    smooth = pd.DataFrame(lowpass(raw, dt) if step > 1 else raw, columns=chans).iloc[::step]
    rho = float(np.median(2.0 * d["qbar_psf"] / (d["tas_kt"] * FT_PER_KT) ** 2))
    sound = float(np.median(d["tas_kt"] * FT_PER_KT / d["mach"]))
    n = len(smooth)
    u = np.column_stack([smooth[c] for c in structure.inputs] + [np.full(n, rho), np.full(n, sound)])
    z = smooth[list(structure.outputs)].to_numpy()
    x0 = smooth[list(structure.states)].to_numpy()[0]
    rec = Record(u, z, dt * step, x0, name=log.point, t_s=d["t_s"].to_numpy()[::step])
    return rec, {
        "rho": rho,
        "v": float(smooth["tas_kt"].mean()),
        "gamma_rad": float(np.mean(smooth["theta_deg"] - smooth["alpha_deg"])),
        "mass": float(d["mass_slug"].mean()),
        "g": effective_gravity(d),
        "scatter": smooth[list(structure.states)].std().to_numpy(),
    }


def group_model(logs: Sequence[Log], fits: Sequence[PointFit], structure: Structure):
    """The point model of one status point's logs fitted together, their records and the starting values.

    Returns
    -------
    model : StateSpaceModel
    records : list of Record
    start : dict
        The model's parameters from the equation-error fits (their mean over the logs).
    air : dict
        Mean airspeed [ft/s], density [slug/ft^3], mass [slug], and the records' state scatter.
    """
    recs, airs = zip(*(_record(log, structure) for log in logs))
    g, inertia = logs[0].meta["geometry"], logs[0].meta["inertia_slugft2"]
    ref = fits[0].reference
    air = {k: float(np.mean([a[k] for a in airs])) for k in ("rho", "v", "gamma_rad", "mass", "g")}
    air["scatter"] = np.mean([a["scatter"] for a in airs], axis=0)
    airframe = Airframe(
        mass=air["mass"],
        area=g["S_ft2"],
        chord=g["cbar_ft"],
        iyy=inertia["iyy"],
        v0=air["v"],
        thrust_angle_rad=0.0,
        thrust_arm=-g.get("thrust_z_arm_ft", 0.0),
        g=air["g"],
    )
    terms = {c: [MODEL_REGRESSOR[t] for t in structure.terms.get(c, ())] for c in COEFFS}
    offsets = {
        "alpha_rad": ref.alpha_deg * D2R,
        "elevator_rad": ref.elevator_deg * D2R,
        "stabilizer_rad": ref.stabilizer_deg * D2R,
        "mach": ref.mach,
        "gamma_rad": air["gamma_rad"],
    }
    inputs = tuple(CHANNEL[c][0] for c in structure.inputs) + ("rho", "a")
    model = longitudinal(
        airframe,
        terms,
        inputs=inputs,
        offsets=offsets,
        outputs=[CHANNEL[c][0] for c in structure.outputs],
        states=[CHANNEL[c][0] for c in structure.states],
    )
    start = {}
    for c in structure.fitted:
        for t in structure.terms[c]:
            vals = [float(f.fits[c].params[t]) for f in fits if t in f.fits[c].params.index]
            start[param_name(c, t)] = float(np.mean(vals)) if vals else 0.0
    return model, list(recs), start, air


def supported(logs: Sequence[Log], fits: Sequence[PointFit], structure: Structure) -> Structure:
    """``structure`` without the terms the point's records do not excite, each with the reason: those
    the equation-error fits left out (a regressor that hardly varied, or varied with another), and
    alpha's square when it varies independently of alpha by less than :data:`MIN_CURVATURE_DEG2`
    (over a few degrees of alpha a curvature is a slope: the lift slope would take what the
    curvature cannot be told from)."""
    for c in structure.fitted:
        for t in structure.terms[c]:
            if t == "const" or any(t in f.fits[c].params.index for f in fits):
                continue
            why = next((f.fits[c].unexcited[t] for f in fits if t in f.fits[c].unexcited), "not excited")
            structure = structure.without(c, t, f"not excited ({why})")
    if any("dalpha2_rad2" in structure.terms[c] for c in structure.fitted):
        spread = curvature_deg2(logs, fits)
        if spread < MIN_CURVATURE_DEG2:
            for c in structure.fitted:
                if "dalpha2_rad2" in structure.terms[c]:
                    structure = structure.without(
                        c,
                        "dalpha2_rad2",
                        f"not excited (alpha squared varies {spread:.2g} "
                        f"deg^2 apart from alpha, below {MIN_CURVATURE_DEG2:g})",
                    )
    return structure


def curvature_deg2(logs: Sequence[Log], fits: Sequence[PointFit]) -> float:
    """The standard deviation of alpha's square about the reference that a line in alpha does not
    explain, over the records together [deg^2]."""
    parts = [regressors(log, fit.reference)[["dalpha_rad", "dalpha2_rad2"]].to_numpy() for log, fit in zip(logs, fits)]
    a, a2 = np.vstack(parts).T
    x = np.column_stack([np.ones_like(a), a])
    rest = a2 - x @ np.linalg.lstsq(x, a2, rcond=None)[0]
    return float(np.std(rest)) / D2R**2


def disagreement(res, fits: Sequence[PointFit], used: Structure) -> list[tuple[str, str, str]]:
    """The lift and drag control and curvature terms (of the default structure) on which the
    time-domain estimates and the equation error's disagree by more than :data:`AGREE_SE` combined
    standard errors (coloured): (coefficient, term, why) each. Where two methods with different error
    models disagree on such a term, the records do not determine it (an elevator that moved with alpha,
    a vane's lag, a curvature along a valley of the cost): left out, it cannot bend the lift slope and
    the pitch damping."""
    found = []
    for c in ("CL", "CD"):
        for t in used.terms.get(c, ()):
            if t not in SECONDARY:
                continue
            ee = [(float(f.fits[c].params[t]), float(f.fits[c].bse[t])) for f in fits if t in f.fits[c].params.index]
            if not ee:
                continue
            v_ee, se_ee = np.mean([v for v, _ in ee]), np.sqrt(np.mean([se**2 for _, se in ee]))
            name = param_name(c, t)
            v, se = float(res.params[name]), float(res.bse_coloured[name])
            if not np.isfinite(v) or abs(v - v_ee) > AGREE_SE * np.hypot(se, se_ee):
                found.append(
                    (
                        c,
                        t,
                        f"equation error and {NAMES[res.method]} disagree on it ({v_ee:.3g} +- "
                        f"{se_ee:.2g} against {v:.3g} +- {se:.2g}): the records do not determine it",
                    )
                )
    return found


def estimator(model, records, start, method: str, air: dict, max_iter: int | None = None):
    """The output-error or filter-error estimator of a point model (its own start and step control)."""
    outputs = set(model.outputs)
    kw = {} if max_iter is None else {"max_iter": max_iter}
    if method == "oe":
        return OutputError(
            model, records, start, x0_free=model.states, biases=[b for b in BIASED if b in outputs], **kw
        )
    if method == "fe":
        return FilterError(model, records, start, F0_SHARE * np.maximum(air["scatter"], 1e-6), **kw)
    raise ValueError(f"method must be one of {METHODS}, not {method!r}")


def derivatives(params: dict, air: dict, geometry: dict, iyy: float) -> dict:
    """The dimensional short-period derivatives of coefficient estimates at the record's mean
    airspeed and density: ``Z_x = -qbar S CL_x / (m V)``, ``M_x = qbar S cbar Cm_x / Iy`` for alpha and
    the controls, times ``cbar / (2 V)`` for q."""
    qs = 0.5 * air["rho"] * air["v"] ** 2 * geometry["S_ft2"]
    c, v, m = geometry["cbar_ft"], air["v"], air["mass"]
    out = {}
    for term, name, scale in (
        ("dalpha_rad", "alpha_per_s", 1.0),
        ("qhat_rad", "q", c / (2 * v)),
        ("delevator_rad", "de_per_s", 1.0),
        ("dstabilizer_rad", "dh_per_s", 1.0),
    ):
        if ("CL", term) in params:
            out[f"Z_{name}"] = -qs * params[("CL", term)] * scale / (m * v)
        if ("Cm", term) in params:
            out[f"M_{name}".replace("_per_s", "_per_s2") if term != "qhat_rad" else "M_q_per_s"] = (
                qs * c * params[("Cm", term)] * scale / iyy
            )
    return out


def refine_group(
    logs: Sequence[Log],
    fits: Sequence[PointFit],
    method: str,
    structure: Structure = DEFAULT,
    max_iter: int | None = None,
) -> list[PointFit]:
    """The eq. (3) fits of one status point's ``logs`` re-estimated together by output error
    (``oe``) or filter error (``fe``).

    The per-coefficient results keep the equation-error shape (so the linear and nonlinear gear
    models follow from these estimates unchanged): parameters, ``bse`` the bound corrected for
    coloured residuals, ``bse_white`` the Cramér-Rao bound, and the coefficient residuals the
    estimates leave on each log's measured eq. (1) coefficients. A coefficient the structure
    leaves out keeps its equation-error fit, labelled ``ee``. When the estimator does not
    converge, every coefficient keeps its equation-error fit, labelled ``ee``, and each
    :class:`PointFit` carries the failure (``failure``: the method and the reason).

    In the default structure the terms the records do not excite are left out first
    (:func:`supported`); after the fit (converged, or stopped at the estimator's own limit), the
    lift and drag control and curvature terms on which it and the equation error disagree
    (:func:`disagreement`) are left out and the fit made again.

    Parameters
    ----------
    logs, fits : sequence
        The logs and their equation-error fits (:func:`identify.models.fit_baseline`), one point's.
    method : {"ee", "oe", "fe"}
    structure : Structure
        The terms, states, outputs and inputs; the terms no record excited are left out.
    max_iter : int, optional
        The estimator's iteration limit (default: its own).
    """
    if method == "ee":
        return list(fits)
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, not {method!r}")
    used = supported(logs, fits, structure)
    while True:
        model, recs, start, air = group_model(logs, fits, used)
        try:
            res = estimator(model, recs, start, method, air, max_iter).fit()
        except (ValueError, np.linalg.LinAlgError) as exc:
            return [replace(f, failure={"method": method, "reason": f"the estimator failed: {exc}"}) for f in fits]
        # a structure the user named is fitted as named; a fit stopped at the user's iteration limit is reported
        if structure.source != DEFAULT.source or not (res.converged or max_iter is None):
            break
        split = disagreement(res, fits, used)
        if not split:
            break
        for term in split:
            used = used.without(*term)
    info = {"method": method, "records": [log.point for log in logs], "structure": used.to_dict()}
    info.update(
        converged=bool(res.converged),
        iterations=res.iterations,
        reason=res.reason,
        cost=res.cost,
        R={k: float(v) for k, v in res.R.items()},
    )
    if not res.converged or not np.all(np.isfinite(res.params)):
        return [
            replace(f, failure={"method": method, "reason": res.reason or "no finite estimates"}, timedomain=info)
            for f in fits
        ]
    est = {(c, t): float(res.params[param_name(c, t)]) for c in used.fitted for t in used.terms[c]}
    g = logs[0].meta["geometry"]
    info["derivatives"] = derivatives(est, air, g, logs[0].meta["inertia_slugft2"]["iyy"])
    info["nuisance"] = {k: float(v) for k, v in res.params.items() if "[" in k or k.startswith("F.")}
    out = []
    for log, fit in zip(logs, fits):
        edge = int(round(EDGE_S / sample_interval(log)))
        inner = slice(edge, len(log.data) - edge)
        y = filtered_frame(log, coefficients(log.data, log.meta)).iloc[inner]
        x = filtered_frame(log, regressors(log, fit.reference)).iloc[inner]
        new = dict(fit.fits)
        for c in used.fitted:
            terms = list(used.terms[c])
            names_c = [param_name(c, t) for t in terms]
            params = pd.Series([est[(c, t)] for t in terms], index=terms)
            fitted = x[terms].to_numpy() @ params.to_numpy()
            resid = y[c].to_numpy() - fitted
            ss_tot = float(np.sum((y[c] - y[c].mean()) ** 2))
            bse = pd.Series(res.bse_coloured[names_c].to_numpy(), index=terms)
            # C0 is about the reference state, itself a mean of measured samples (as fit_baseline has it)
            extra = sum((params[r] * se) ** 2 for r, se in fit.reference.se if r in params.index)
            bse["const"] = float(np.sqrt(bse["const"] ** 2 + extra))
            unexcited = {t: why for t, why in fit.fits[c].unexcited.items() if t not in terms}
            for t in fit.fits[c].params.index:
                if t not in terms:
                    unexcited[t] = used.left_out.get(f"{c} {t}", f"not in the {NAMES[method]} structure")
            new[c] = replace(
                fit.fits[c],
                params=params,
                bse=bse,
                bse_white=pd.Series(res.bse[names_c].to_numpy(), index=terms),
                resid=resid,
                fitted=fitted,
                y=y[c].to_numpy(),
                unexcited=unexcited,
                rsquared=1.0 - float(resid @ resid) / ss_tot if ss_tot > 0 else float("nan"),
                cov=None,
                method=method,
                converged=True,
            )
        out.append(replace(fit, fits=new, timedomain=info))
    return out


def refine_point(
    log: Log, fit: PointFit, method: str, structure: Structure = DEFAULT, max_iter: int | None = None
) -> PointFit:
    """:func:`refine_group` of one log."""
    return refine_group([log], [fit], method, structure, max_iter)[0]
