"""The data compatibility's estimate: initial states first, then the instrument errors the logs
excite, stage by stage, with delete-one-log jackknife standard errors."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from identify.compat.config import CompatSettings
from identify.compat.reconstruction import (
    ESSENTIAL,
    INS,
    body_rotations,
    body_to_ned,
    delayed,
    gauss_newton,
    gust_basis,
    heading_change,
    integrated_attitude,
    noise_level,
    prepare,
    select,
    shift_columns,
    unexcited_parameters,
    velocity_responses,
)
from identify.compat.result import (
    BLOCK_S,
    D2R,
    DRYDEN_LENGTH_FT,
    FT_PER_KT,
    GUST_PRIOR_FLOOR_FPS,
    MAX_LOGS,
    PRUNE_FIRST,
    CompatResult,
    at_cg,
    columns_of,
    documented_positions,
    instrument_parameters,
)
from identify.logs import Log
from infra.pool import pmap


def estimate(  # noqa: C901
    logs: list[Log],
    replicate: bool = False,
    jobs: int = 1,
    settings: CompatSettings | None = None,
    wanted: frozenset[str] | None = None,
) -> CompatResult:
    """Estimate the instrument errors from the logs (see the module notes).

    Parameters
    ----------
    logs : list of Log or LogHead
        Every log; at most :data:`identify.compat.result.MAX_LOGS` of them are reconstructed, and
        only those are read (:meth:`identify.logs.LogHead.read`).
    replicate : bool
        A replicate of :func:`_whole_jackknife` (it makes none of its own).
    jobs : int
        Worker processes for those replicates.
    settings : CompatSettings, optional
        The decision thresholds (None: the defaults); every parameter of the result carries them, and
        the replicates get them.
    wanted : frozenset of str, optional
        The parameters whose estimate is read (None: every one): of two errors the data cannot tell
        apart, the other reading of one not wanted is not computed (a replicate reads only the
        corrections its jackknife is for).

    Returns
    -------
    CompatResult
    """
    settings = settings or CompatSettings()
    params = instrument_parameters(settings)
    by = {p.name: p for p in params}
    positions = documented_positions(logs)
    missing = [c for c in ESSENTIAL if not logs or not all(c in lg.columns for lg in logs)]
    # a channel an import map gave as a constant is no measurement: not reconstructed, nor compared with
    constant = set().union(*(lg.meta.get("imported", {}).get("constants", ()) for lg in logs)) if logs else set()
    fixed = [c for c in ESSENTIAL if c in constant and c not in missing]
    if not missing and not fixed and len(logs) == 1 and not replicate:
        pieces = segments(logs[0].read(), settings.one_log_segment_s)
        if len(pieces) >= settings.one_log_segments:
            result = estimate(pieces, jobs=jobs, settings=settings)
            for p in result.parameters:
                if p.name in ONE_LOG_UNMEASURED and p.identifiable:
                    p.identifiable = False
                    p.reason = (
                        f"one log: its segments misjudge how much the turbulence holds of the air data "
                        f"(estimated {p.estimate:+.3g} +- {p.se:.2g} {p.unit})"
                    )
            return replace(result, logs=[logs[0].path], segments=len(pieces))
    if missing or fixed or len(logs) < 2:
        why = (
            f"{missing[0]} is not logged"
            if missing
            else f"{fixed[0]} is a constant of the import map, not a measurement"
            if fixed
            else (
                f"one log shorter than {settings.one_log_segments} segments of {settings.one_log_segment_s:g} s "
                "(its standard errors come from the spread between logs, or between a log's segments)"
            )
        )
        for p in params:
            p.identifiable, p.reason = False, f"no reconstruction: {why}"
        return CompatResult(params, [lg.path for lg in logs], {}, positions)
    chosen = [lg.read() for lg in select(logs)]
    unused = attitude_jumps(chosen, settings.attitude_jump_deg)
    broken = [c for c in ESSENTIAL if c in unused]
    if broken:
        for p in params:
            p.identifiable, p.reason = False, f"no reconstruction: {broken[0]} {unused[broken[0]]}"
        return CompatResult(params, [lg.path for lg in logs], {}, positions, unused=unused)
    constant = constant | set(unused)
    data = prepare(
        [
            replace(
                lg,
                data=pd.DataFrame(
                    at_cg(
                        columns_of(
                            lg.data.drop(columns=sorted(constant & set(lg.data.columns))) if constant else lg.data
                        ),
                        positions,
                        accelerometers_only=True,
                    ),
                    index=lg.data.index,
                ),
            )
            for lg in chosen
        ]
    )
    x_doc = positions.get("alpha_deg", [None])[0]
    xb_doc = positions.get("beta_deg", [x_doc])[0]
    if x_doc is not None:
        by["alpha_deg.position"].identifiable = False
        by["alpha_deg.position"].reason = f"documented in the logs: {x_doc:g} ft ahead of the CG"
    L = len(chosen)
    mask = data.mask
    valid = mask.ravel()
    sig = {
        c: noise_level(data.ch[c], mask, fl)
        for c, fl in (
            ("theta_deg", 0.002 * D2R),
            ("phi_deg", 0.002 * D2R),
            ("psi_deg", 0.002 * D2R),
            ("alpha_deg", 0.005 * D2R),
            ("beta_deg", 0.005 * D2R),
            ("tas_kt", 0.02 * FT_PER_KT),
            ("alt_ft", 0.5),
            ("vn_fps", 0.02),
            ("ve_fps", 0.02),
            ("vd_fps", 0.02),
        )
    }
    rms: dict = {}
    covs: list = []

    # ---- stage 1: attitude from the gyros
    s1 = [
        "p_dps.bias",
        "q_dps.bias",
        "r_dps.bias",
        "theta_deg.scale",
        "theta_deg.delay",
        "phi_deg.scale",
        "phi_deg.delay",
    ]
    outs1 = [c for c in ("theta_deg", "phi_deg", "psi_deg") if c in data.present]

    # the gyro biases (and initial angles) of the last few evaluations -> their rotations (attitude): a
    # Jacobian's differences in a scale or a delay keep both, one in an initial angle the rotations
    rotations, attitudes = {}, {}

    def model1(x):
        v = dict(zip(s1, x[: len(s1)]))
        per = x[len(s1) :].reshape(L, 3)
        biases = (v["p_dps.bias"] * D2R, v["q_dps.bias"] * D2R, v["r_dps.bias"] * D2R)
        key = np.array(biases).tobytes()  # bit for bit
        th, ph, ps = attitudes.get(key + per.tobytes()) or _keep(
            attitudes,
            key + per.tobytes(),
            integrated_attitude(
                data,
                *biases,
                per[:, 0],
                per[:, 1],
                per[:, 2],
                steps=rotations[key] if key in rotations else _keep(rotations, key, body_rotations(data, *biases)),
            ),
        )
        return {
            "theta_deg": (1 + v["theta_deg.scale"]) * delayed(th, data.t, v["theta_deg.delay"]),
            "phi_deg": (1 + v["phi_deg.scale"]) * delayed(ph, data.t, v["phi_deg.delay"]),
            "psi_deg": ps,
        }, (th, ph, ps)

    def resid1(x):
        m, _ = model1(x)
        return np.concatenate([((data.ch[c] - m[c]) / sig[c]).ravel()[valid] for c in outs1])

    x1 = np.concatenate(
        [np.zeros(len(s1)), np.stack([data.ch[c][:, 0] for c in ("theta_deg", "phi_deg", "psi_deg")], 1).ravel()]
    )
    rows1 = np.tile(np.repeat(np.arange(L), mask.sum(1)), len(outs1))
    if outs1:
        x1 = _solve_stage(
            resid1,
            x1,
            s1,
            by,
            3,
            L,
            rows1,
            outs1,
            sig,
            valid,
            rms,
            mask,
            lambda x: {c: model1(x)[0][c] for c in outs1},
            data,
            covs=covs,
            settings=settings,
            wanted=wanted,
        )
    v1 = dict(zip(s1, x1[: len(s1)]))
    _, (th_r, ph_r, ps_r) = model1(x1)

    # ---- stage 2: velocity, air data and altitude from the accelerometers
    rates = tuple(data.ch[c] - v1[f"{c}.bias"] * D2R for c in ("p_dps", "q_dps", "r_dps"))
    Phi, X, HPhi, HX = velocity_responses(data, rates, th_r, ph_r)
    s2 = [
        "ax_fps2.bias",
        "ay_fps2.bias",
        "az_fps2.bias",
        "theta_deg.bias",
        "phi_deg.bias",
        "alpha_deg.bias",
        "alpha_deg.scale",
        "alpha_deg.delay",
        "alpha_deg.position",
        "beta_deg.bias",
        "beta_deg.scale",
        "beta_deg.delay",
        "tas_kt.bias",
        "tas_kt.scale",
        "tas_kt.delay",
    ]
    ins = all(c in data.present for c in INS)
    outs2 = [c for c in ("alpha_deg", "beta_deg", "tas_kt", "alt_ft") + (INS[1:] if ins else ()) if c in data.present]
    q_c, r_c = rates[1], rates[2]

    gust = gust_basis(data)
    minus_gust = -gust
    minus_gust_valid = minus_gust.reshape(-1, gust.shape[2])[valid]
    k_gust = gust.shape[2]
    n_wind = 2 if ins else 0  # a steady horizontal wind per log, where the INS tells air from ground
    g0 = 4 + n_wind
    n_per = g0 + 3 * k_gust
    b2n = body_to_ned(th_r, ph_r, ps_r)
    wind_dirs = np.swapaxes(b2n, -1, -2)[..., :2]  # (L, n, 3, 2): north and east in body axes
    ins_phi = np.einsum("lnij,lnjk->lnik", b2n, Phi, optimize=True) if ins else None  # d(v_NED)/d(v0)

    forcing = [s2.index(n) for n in ("ax_fps2.bias", "ay_fps2.bias", "az_fps2.bias", "theta_deg.bias", "phi_deg.bias")]
    last_state: dict = {}  # the parameters the flight path depends on, bit for bit -> the path

    def state(x):
        """Shared values, per-log values, air-relative body velocity, altitude and the inertial
        velocity north-east-down (if the logs have it). A difference in an air-data error keeps the
        flight path: it is computed again only when the parameters it depends on change."""
        v = dict(zip(s2, x[: len(s2)]))
        key = x[forcing].tobytes() + x[len(s2) :].tobytes()
        if key not in last_state:
            per = x[len(s2) :].reshape(L, n_per).copy()
            lin = np.concatenate(
                [
                    [1.0],
                    [v["ax_fps2.bias"], v["ay_fps2.bias"], v["az_fps2.bias"]],
                    [v["theta_deg.bias"] * D2R, v["phi_deg.bias"] * D2R],
                ]
            )
            inertial = np.einsum("lnij,lj->lni", Phi, per[:, :3], optimize=True) + X @ lin
            h = per[:, 3:4] + np.einsum("lnj,lj->ln", HPhi, per[:, :3], optimize=True) + HX @ lin
            # air = inertial - gust
            vel = inertial - np.einsum("lnk,lck->lnc", gust, per[:, g0:].reshape(L, 3, k_gust), optimize=True)
            if n_wind:
                vel = vel - np.einsum("lncw,lw->lnc", wind_dirs, per[:, 4:6], optimize=True)
            ned = np.moveaxis(np.einsum("lnij,lnj->lni", b2n, inertial, optimize=True), -1, 0) if ins else None
            last_state.clear()
            last_state[key] = per, vel, h, ned
        return (v, *last_state[key])

    def model2(x, only: str | None = None):
        """The outputs at ``x`` (only the air-data channel ``only``, if given)."""
        v, _, vel, h, ned = state(x)
        u, vv, w = vel[..., 0], vel[..., 1], vel[..., 2]
        xh = v["alpha_deg.position"] if x_doc is None else x_doc
        xb = xh if xb_doc is None else xb_doc
        out = {}
        if only in (None, "beta_deg", "tas_kt"):
            vt = np.sqrt(u**2 + vv**2 + w**2)
        if only in (None, "alpha_deg"):
            alpha_v = np.arctan2(w - q_c * xh, u)
            out["alpha_deg"] = (1 + v["alpha_deg.scale"]) * delayed(alpha_v, data.t, v["alpha_deg.delay"]) + v[
                "alpha_deg.bias"
            ] * D2R
        if only in (None, "beta_deg"):
            beta_v = np.arcsin(np.clip((vv + r_c * xb) / vt, -1, 1))
            out["beta_deg"] = (1 + v["beta_deg.scale"]) * delayed(beta_v, data.t, v["beta_deg.delay"]) + v[
                "beta_deg.bias"
            ] * D2R
        if only in (None, "tas_kt"):
            out["tas_kt"] = (1 + v["tas_kt.scale"]) * delayed(vt, data.t, v["tas_kt.delay"]) + v[
                "tas_kt.bias"
            ] * FT_PER_KT
        if only is None:
            out["alt_ft"] = h
            out.update(dict(zip(INS[1:], ned)) if ins else {})
        return out

    prior = {"fps": 0.0}  # the gusts' prior standard deviation [ft/s]; 0: none

    def resid2(x):
        m = model2(x)
        e = np.concatenate([((data.ch[c] - m[c]) / sig[c]).ravel()[valid] for c in outs2])
        if not prior["fps"]:
            return e
        return np.concatenate([e, x[len(s2) :].reshape(L, n_per)[:, g0:].ravel() / prior["fps"]])

    def column2(x, i: int):
        """A Jacobian column's residual rows at ``x``, where the shared parameter ``i`` (just moved) is
        an air-data channel's bias, scale or delay: that channel's rows alone move (None: all may)."""
        c, _, e = s2[i].partition(".")
        if c not in ("alpha_deg", "beta_deg", "tas_kt") or e == "position" or c not in outs2:
            return None
        b, n_valid = outs2.index(c), int(valid.sum())
        return slice(b * n_valid, (b + 1) * n_valid), ((data.ch[c] - model2(x, c)[c]) / sig[c]).ravel()[valid]

    def perlog2(x):
        """d(residual)/d(each log's initial velocity, altitude and gust coefficients), by the chain rule."""
        v, _, vel, _, _ = state(x)
        u, vv, w = vel[..., 0], vel[..., 1], vel[..., 2]
        xh = v["alpha_deg.position"] if x_doc is None else x_doc
        xb = xh if xb_doc is None else xb_doc
        vt2 = u**2 + vv**2 + w**2
        vt = np.sqrt(vt2)
        wv, vb = w - q_c * xh, vv + r_c * xb
        den_a = u**2 + wv**2
        sb = np.clip(vb / vt, -0.999999, 0.999999)
        cb = np.sqrt(1 - sb**2)
        d_out = {  # derivative of each air-data output by (u, v, w), before scale and delay
            "alpha_deg": np.stack([-wv / den_a, np.zeros_like(u), u / den_a], -1),
            "beta_deg": np.stack([-vb * u / (vt2 * vt), (1 / vt - vb * vv / (vt2 * vt)), -vb * w / (vt2 * vt)], -1)
            / cb[..., None],
            "tas_kt": vel / vt[..., None],
        }
        # d vel / d per-log parameters: Phi for the initial velocity, -basis for the gust coefficients,
        # minus the north and east directions for the wind
        n_valid = int(valid.sum())
        n_out = len(outs2) * n_valid
        out = np.zeros((n_out + (L * 3 * k_gust if prior["fps"] else 0), n_per))  # the gusts' prior rows last
        d = None  # one buffer for every air-data output: all its columns but the altitude's are written
        for b, c in enumerate(outs2):
            block = out[b * n_valid : (b + 1) * n_valid]
            if c == "alt_ft":
                block[:, :3] = HPhi.reshape(-1, 3)[valid]
                block[:, 3] = 1.0
            elif c in INS:
                block[:, :3] = ins_phi[..., INS.index(c) - 1, :].reshape(-1, 3)[valid]
            else:
                dc = d_out[c]
                by_v0 = np.einsum("lnc,lncj->lnj", dc, Phi, optimize=True)
                by_wind = -np.einsum("lnc,lncw->lnw", dc, wind_dirs, optimize=True) if n_wind else None
                if v[f"{c}.delay"] == 0.0:  # the valid rows alone, as they are
                    block[:, :3] = by_v0.reshape(-1, 3)[valid]
                    if n_wind:
                        block[:, 4:6] = by_wind.reshape(-1, 2)[valid]
                    dv = dc.reshape(-1, 3)[valid]
                    for j in range(3):
                        np.multiply(
                            dv[:, j, None], minus_gust_valid, out=block[:, g0 + j * k_gust : g0 + (j + 1) * k_gust]
                        )
                else:  # shifted in time: each row reads its neighbours
                    d = np.zeros((L, vel.shape[1], n_per)) if d is None else d
                    d[..., :3] = by_v0
                    if n_wind:
                        d[..., 4:6] = by_wind
                    for j in range(3):
                        np.multiply(dc[..., j, None], minus_gust, out=d[..., g0 + j * k_gust : g0 + (j + 1) * k_gust])
                    np.compress(valid, shift_columns(d, data.t, v[f"{c}.delay"]).reshape(-1, n_per), axis=0, out=block)
                block *= 1 + v[f"{c}.scale"]
            block /= -sig[c]
        if prior["fps"]:
            out[n_out:].reshape(L, 3 * k_gust, n_per)[:, :, g0:] = np.eye(3 * k_gust) / prior["fps"]
            steady = np.zeros((len(out), 3))  # d(residual)/d(a steady gust along each body axis)
            for b, c in enumerate(outs2):
                if c in d_out:
                    d = -d_out[c] * mask[..., None]
                    steady[b * n_valid : (b + 1) * n_valid] = (
                        shift_columns(d, data.t, v[f"{c}.delay"]).reshape(-1, 3)[valid]
                        * (1 + v[f"{c}.scale"])
                        / -sig[c]
                    )
            prior["steady"] = steady
        return out

    a0, b0 = data.ch["alpha_deg"][:, 0], data.ch["beta_deg"][:, 0]
    v0 = data.ch["tas_kt"][:, 0]
    init = np.stack(
        [v0 * np.cos(a0) * np.cos(b0), v0 * np.sin(b0), v0 * np.sin(a0) * np.cos(b0), data.ch["alt_ft"][:, 0]], 1
    )
    x2 = np.concatenate([np.zeros(len(s2)), np.hstack([init, np.zeros((L, n_wind + 3 * k_gust))]).ravel()])
    rows2 = np.tile(np.repeat(np.arange(L), mask.sum(1)), len(outs2))
    turned = heading_change(data) >= settings.turn_span_deg if n_wind else np.zeros(L, bool)
    if turned.all():
        for e in ("bias", "scale"):
            by[f"tas_kt.{e}"].identifiable = False
            by[f"tas_kt.{e}"].reason = (
                "every log turns: the gusts' size, which tells a steady wind from an "
                "airspeed error in a turn, needs a straight log too"
            )
    elif turned.any():
        # In a turn a steady wind turns in body axes as slowly as the gusts' splines move: without a
        # prior on the gusts' size the two trade freely, and with them an airspeed scale or bias. The
        # prior is the turbulence the straight logs show (the vertical gust, as Dryden's isotropic).
        prior["fps"] = max(
            estimate(
                [lg for lg, t in zip(chosen, turned) if not t], replicate=True, settings=settings, wanted=frozenset()
            ).turbulence_fps,
            GUST_PRIOR_FLOOR_FPS,
        )
        rows2 = np.concatenate([rows2, np.repeat(np.arange(L), 3 * k_gust)])
        # one log pins the airspeed error: time blocks, not logs, are the clusters of its uncertainty
        label = (np.arange(L)[:, None] * 100_000 + np.floor(data.t / BLOCK_S)).ravel()[valid]
        blocks2 = np.concatenate([np.tile(label, len(outs2)), np.repeat(np.arange(L) * 100_000 - 1, 3 * k_gust)])
        # the splines are zero-mean over each log: the mean gust over a log of T seconds, of variance
        # sigma^2 2 tau / T for a correlation time tau = L / V (Dryden), is the error they leave out
        span = np.array([data.t[i][mask[i]][-1] for i in range(L)])
        speed = np.array([np.median(data.ch["tas_kt"][i][mask[i]]) for i in range(L)])
        prior["offset_sd"] = prior["fps"] * np.sqrt(2.0 * DRYDEN_LENGTH_FT / speed / span)
    x2 = _solve_stage(
        resid2,
        x2,
        s2,
        by,
        n_per,
        L,
        rows2,
        outs2,
        sig,
        valid,
        rms,
        mask,
        model2,
        data,
        perlog2,
        covs,
        (blocks2, lambda: prior["steady"], prior["offset_sd"]) if prior["fps"] else None,
        column2,
        settings,
        wanted,
    )
    per = x2[len(s2) :].reshape(L, n_per)
    w_gust = np.einsum("lnk,lk->ln", gust, per[:, g0 + 2 * k_gust : g0 + 3 * k_gust], optimize=True)
    turbulence = float(np.sqrt(np.mean(w_gust[mask] ** 2)))
    if turbulence > settings.turbulent_fps:
        for c in ("alpha_deg", "beta_deg", "tas_kt"):
            p = by[f"{c}.delay"]
            if p.identifiable:
                p.identifiable = False
                p.reason = (
                    f"turbulence: the reconstruction's vertical gust is {turbulence:.2g} ft/s RMS, and the "
                    f"aircraft's answer to it biases the kinematic time shift by tens of ms (fly the "
                    f"compatibility manoeuvres in calm air); kinematic estimate {p.estimate * 1000:+.0f} ms"
                )
    for ch, k in (("theta_deg", D2R), ("phi_deg", D2R), ("alpha_deg", D2R), ("beta_deg", D2R), ("tas_kt", FT_PER_KT)):
        if ch in rms:
            rms[ch] = {key: v / k for key, v in rms[ch].items()}
    result = CompatResult(params, [lg.path for lg in chosen], rms, positions, covs, turbulence, unused=unused)
    if not replicate and L >= 3 and result.applied:
        _whole_jackknife(result, chosen, jobs, settings)
    return result


#: The errors one log's reconstruction does not estimate: those the air data's turbulence holds
#: (:attr:`CompatSettings.one_log_segment_s`); the diagnosis takes them as large as specified.
ONE_LOG_UNMEASURED = frozenset(
    [f"{c}.{e}" for c in ("alpha_deg", "beta_deg", "tas_kt") for e in ("bias", "scale", "delay")]
    + ["alpha_deg.position", "ax_fps2.bias", "ay_fps2.bias", "az_fps2.bias", "theta_deg.bias", "phi_deg.bias"]
)


def segments(log: Log, least_s: float) -> list[Log]:
    """``log`` cut into equal segments at least ``least_s`` long [s] (at most
    :data:`~identify.compat.result.MAX_LOGS`), each a log of its own; ``[log]`` if it is shorter than two."""
    t = log.data["t_s"].to_numpy()
    k = min(int((t[-1] - t[0]) // least_s), MAX_LOGS) if len(t) > 1 else 0
    if k < 2:
        return [log]
    piece = np.minimum(((t - t[0]) / (t[-1] - t[0]) * k).astype(int), k - 1)
    return [
        replace(log, path=f"{log.path}#{i + 1}", data=log.data.loc[piece == i].reset_index(drop=True)) for i in range(k)
    ]


#: The attitude channels :func:`attitude_jumps` checks against the gyros.
ATTITUDES = ("theta_deg", "phi_deg", "psi_deg")


def attitude_jumps(logs: list[Log], limit_deg: float) -> dict[str, str]:
    """The attitude channels that move more than ``limit_deg`` in one sample beyond what the gyros turn them
    by (a heading's full turns unwrapped first), in any of ``logs``: ``{channel: where and by how much}``.

    The gyros' turn is the Euler angles' rate from the body rates and the logged pitch and bank, averaged
    over the sample; a channel or rate the log lacks is not checked.
    """
    out: dict[str, str] = {}
    for lg in logs:
        d = lg.data
        if not all(c in d for c in ("t_s", "p_dps", "q_dps", "r_dps", "theta_deg", "phi_deg")) or len(d) < 2:
            continue
        t = d["t_s"].to_numpy(float)
        p, q, r = (np.radians(d[c].to_numpy(float)) for c in ("p_dps", "q_dps", "r_dps"))
        th, ph = np.radians(d["theta_deg"].to_numpy(float)), np.radians(d["phi_deg"].to_numpy(float))
        rates = {
            "theta_deg": q * np.cos(ph) - r * np.sin(ph),
            "phi_deg": p + (q * np.sin(ph) + r * np.cos(ph)) * np.tan(th),
            "psi_deg": (q * np.sin(ph) + r * np.cos(ph)) / np.cos(th),
        }
        for c in ATTITUDES:
            if c in out or c not in d:
                continue
            x = d[c].to_numpy(float)
            x = np.degrees(np.unwrap(np.radians(x))) if c == "psi_deg" else x
            turn = np.degrees(0.5 * (rates[c][1:] + rates[c][:-1]) * np.diff(t))
            gap = np.abs(np.diff(x) - turn)
            k = int(np.argmax(gap))
            if gap[k] > limit_deg:
                where = Path(lg.path).name.partition("#")[0]  # a segment of one log keeps the log's times
                out[c] = (
                    f"moves by {np.diff(x)[k]:+.1f} deg at t = {t[k + 1]:.2f} s of {where}, where "
                    f"the gyros turn it by {turn[k]:+.2f} deg: not a measurement of the attitude"
                )
    return out


#: Evaluations :func:`estimate` keeps (a Jacobian's differences return to the point they start from).
KEPT_EVALUATIONS = 4


def _keep(kept: dict, key: bytes, value):
    """``value``, kept as ``kept[key]``, the oldest entry dropped past :data:`KEPT_EVALUATIONS`."""
    kept[key] = value
    while len(kept) > KEPT_EVALUATIONS:
        del kept[next(iter(kept))]
    return value


def _replicate(logs: list[Log], settings: CompatSettings, wanted: frozenset[str]) -> CompatResult:
    return estimate(logs, replicate=True, settings=settings, wanted=wanted)


def _whole_jackknife(
    result: CompatResult, logs: list[Log], jobs: int = 1, settings: CompatSettings | None = None
) -> None:
    """The standard errors of the corrections about to be applied on the kinematics' word alone, from
    the whole estimate made again with each log left out (its decisions included: which errors the
    logs excite, which two are confounded), where that spread exceeds the one-step jackknife's. The
    one-step replicates linearise about the full fit; in turbulence the fit's own choices move with
    a log, and an A320 null's vane scale of +2.5 % came out at 10.7 one-step standard errors and 1.8
    whole ones, a stock-737 vane bias of -0.079 deg at 6.6 and 1.0. ``result`` is updated in place,
    its stage covariances scaled alike. The replicates decide by ``settings`` (None: the defaults), as
    the estimate did."""
    L = len(logs)
    settings = settings or CompatSettings()
    wanted = frozenset(p.name for p in result.applied)
    reps = pmap(_replicate, [(logs[:i] + logs[i + 1 :], settings, wanted) for i in range(L)], jobs)
    for p in result.applied:
        # a replicate that cannot estimate it at all (the one log that excites it left out) says nothing
        e = np.array([q.estimate for q in (r.get(p.name) for r in reps) if q.identifiable and np.isfinite(q.estimate)])
        n = len(e)
        whole = float(np.sqrt((n - 1) / n * np.sum((e - e.mean()) ** 2))) if n >= 2 else 0.0
        if not whole > p.se:
            continue
        k = whole / p.se
        p.se_one_step, p.se = p.se, whole
        for names, cov in result.covariance:
            if p.name in names:
                j = names.index(p.name)
                cov[j, :] *= k
                cov[:, j] *= k


def _covariance(blk, blocks: tuple | None) -> np.ndarray:
    """The delete-one-log jackknife; with ``blocks`` (a log turns), the time-block sandwich plus
    the steady gusts the splines leave out (:func:`identify.compat.reconstruction.gauss_newton`)."""
    return blk.cluster_cov() if blocks is None else blk.block_cov() + blk.offset_cov(blocks[2])


def _solve_stage(  # noqa: PLR0913
    residual,
    x,
    names,
    by,
    per,
    L,
    rows,
    outs,
    sig,
    valid,
    rms,
    mask,
    model,
    data,
    perlog=None,
    covs: list | None = None,
    blocks: tuple | None = None,
    column=None,
    settings: CompatSettings | None = None,
    wanted: frozenset[str] | None = None,
) -> np.ndarray:
    """Initial states alone (perfect instruments assumed), then the identifiable instrument
    errors too; parameters the data cannot tell apart (variance inflation above ``settings.max_vif``)
    are fixed at 0.
    ``blocks``: for the standard errors when a log turns (:func:`_covariance`); ``column``: see
    :func:`identify.compat.reconstruction.gauss_newton`; ``wanted``: see :func:`estimate`."""
    ns = len(names)
    free = np.zeros(ns, bool)
    rows = [np.flatnonzero(rows == i) for i in range(L)]  # residual rows of each log
    x, _, e = gauss_newton(residual, x, free, ns, L, per, rows, perlog, column=column)
    n = int(valid.sum())
    for i, c in enumerate(outs):
        rms[c] = {"before": float(np.sqrt(np.mean((e[i * n : (i + 1) * n] * sig[c]) ** 2)))}
    recon = {c: v for c, v in model(x).items()}
    settings = settings or CompatSettings()
    for name, why in unexcited_parameters(data, recon, settings).items():
        if name in by and name in names:
            by[name].identifiable, by[name].reason = False, why
    free[:] = [by[s].identifiable for s in names]
    pairs = []  # (pruned, kept) indices into names
    while True:
        x, blk, e = gauss_newton(residual, x, free, ns, L, per, rows, perlog, robust=blocks, column=column)
        cov = _covariance(blk, blocks)
        idx = np.flatnonzero(free)
        sd = np.sqrt(np.abs(np.diag(cov)))
        if len(idx) < 2:
            break
        corr = cov / np.maximum(np.outer(sd, sd), 1e-300)
        vif = np.diag(np.linalg.pinv(corr))
        if vif.max() <= settings.max_vif:
            break
        # the most inflated parameter goes (of near ties, the latest listed); the one it leans on is confounded
        worst = max(j for j in range(len(idx)) if vif[j] >= 0.9 * vif.max())
        partner = int(np.argmax(np.where(np.arange(len(idx)) == worst, -1.0, np.abs(corr[worst]))))
        if names[idx[partner]] in PRUNE_FIRST and names[idx[worst]] not in PRUNE_FIRST:
            worst, partner = partner, worst  # keep the error eq. (1) feels; the residuals may choose it
        by[names[idx[worst]]].identifiable = False
        by[
            names[idx[worst]]
        ].reason = f"not separable from {names[idx[partner]]} in these manoeuvres (variance inflation {vif[worst]:.0f})"
        by[names[idx[partner]]].reason = f"confounded with {names[idx[worst]]}: the estimate holds both (not applied)"
        by[names[idx[partner]]].confounded_with = names[idx[worst]]
        pairs.append((idx[worst], idx[partner]))
        free[idx[worst]] = False
        x[idx[worst]] = 0.0
    for j, i in enumerate(idx):
        by[names[i]].estimate, by[names[i]].se = float(x[i]), float(sd[j])
    if covs is not None:
        covs.append(([names[i] for i in idx], cov))
    for pruned, kept in pairs:  # the other reading of the same data: the pruned error, its partner at 0
        if not free[kept] or (wanted is not None and names[pruned] not in wanted):
            continue
        alt_free = free.copy()
        alt_free[pruned], alt_free[kept] = True, False
        x_alt = x.copy()
        x_alt[kept] = 0.0
        x_alt, blk_alt, _ = gauss_newton(
            residual, x_alt, alt_free, ns, L, per, rows, perlog, robust=blocks, column=column
        )
        j = int(np.flatnonzero(np.flatnonzero(alt_free) == pruned)[0])
        p = by[names[pruned]]
        p.estimate, p.se = float(x_alt[pruned]), float(np.sqrt(abs(_covariance(blk_alt, blocks)[j, j])))
        p.identifiable, p.confounded_with = True, names[kept]
    for i, c in enumerate(outs):
        rms[c]["after"] = float(np.sqrt(np.mean((e[i * n : (i + 1) * n] * sig[c]) ** 2)))
    return x
