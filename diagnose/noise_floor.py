"""What instrument noise alone can make the diagnosis see.

A named cause must be larger than this. The noise of each channel is estimated
from the logs themselves (second differences; the diagnosis never reads an
instrument profile), then fresh noise of that level is pushed through the whole
residual computation:

- through eq. (1) exactly (the measured coefficients recomputed from noisy channels);
- through the model linearly: its sensitivity to every channel, by JSBSim
  finite differences at a subsample of each log (the evaluation of α̇ and CL²
  from noisy channels included);
- into the regressors (errors-in-variables): the candidate variables are
  recomputed from the noisy channels.

Each realization is filtered and thinned like the real residuals, and the
cause's own terms are fitted to it. The sizes these fits reach are the floor.
"""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pandas as pd

from diagnose.config import current
from diagnose.evaluate import by_log_chunks, in_chunks
from diagnose.residuals import (
    COEFFS,
    FILTERED,
    kept,
    measured_about,
    measured_arrays,
    signature_arrays,
    variable_arrays,
)
from identify.coefficients import coefficient_arrays, coefficients, lift_coefficient
from identify.kinematics import pitch_rate_derivative
from identify.logs import Log
from identify.lsq import solve_normal
from identify.models import lowpass

#: Channels whose sensor noise reaches the residuals or the regressors.
NOISY = (
    "alt_ft",
    "tas_kt",
    "mach",
    "alpha_deg",
    "beta_deg",
    "theta_deg",
    "phi_deg",
    "p_dps",
    "q_dps",
    "r_dps",
    "qdot_dps2",
    "ax_fps2",
    "ay_fps2",
    "az_fps2",
    "qbar_psf",
    "thrust_lbf",
    "elevator_deg",
    "stabilizer_deg",
    "flap_deg",
    "gear_norm",
    "mass_slug",
)
#: The channels each candidate variable is computed from (errors-in-variables needs noise in one).
SOURCES = {
    "gear_norm": ("gear_norm",),
    "alpha_deg": ("alpha_deg",),
    "mach": ("mach",),
    "flap_deg": ("flap_deg",),
    "elevator_deg": ("elevator_deg",),
    "stabilizer_deg": ("stabilizer_deg",),
    "qhat_rad": ("q_dps", "tas_kt"),
    "adothat_rad": (
        "alpha_deg",
        "beta_deg",
        "tas_kt",
        "ax_fps2",
        "az_fps2",
        "p_dps",
        "q_dps",
        "r_dps",
        "theta_deg",
        "phi_deg",
    ),
    # the model's CL at the measured states, and the measured CL a model that reads CL squared is given
    "CL": (
        "alpha_deg",
        "mach",
        "elevator_deg",
        "stabilizer_deg",
        "q_dps",
        "tas_kt",
        "ax_fps2",
        "az_fps2",
        "qbar_psf",
        "thrust_lbf",
        "mass_slug",
    ),
    **{f"thrust_{c}": ("thrust_lbf", "alpha_deg", "qbar_psf") for c in COEFFS},
}
SENSITIVITY_EVERY_S = 0.5
#: Below this a coefficient change is beyond the evaluation's own resolution (it reproduces
#: noise-free logs to about 1e-7).
RESOLUTION = 1e-5
#: Realizations a worker computes together (they share per-log work; each holds its residual data).
#: On the paper matrix the noise floor is where a diagnosis worker peaks: 285 MB RSS with 4, of which
#: 200 MB are the shared pages every worker starts with (290-310 MB with 5, 0.07 s faster per worker).
REALIZATION_BATCH = 4


def channel_noise(logs: list[Log]) -> dict[str, float]:
    """White-noise level (1 sigma) of each channel, in its own units.

    From the second differences, which a smooth signal sampled fast hardly
    feeds: ``1.4826 MAD(d2x) / sqrt(6)`` per log (robust to steps and
    spikes), the median over the logs.
    """
    levels: dict[str, list[float]] = {}
    for log in logs:  # every channel of a log at once: a median per call costs more than the data
        names = [ch for ch in NOISY if ch in log.data]
        d2 = (
            np.diff(np.column_stack([log.data[ch].to_numpy(dtype=float) for ch in names]), 2, axis=0)
            if names
            else np.zeros((0, 0))
        )
        if len(d2):
            mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
            for ch, m in zip(names, mad):
                levels.setdefault(ch, []).append(1.4826 * float(m) / np.sqrt(6.0))
    return {ch: float(np.median(levels[ch])) for ch in NOISY if ch in levels}


def _measured(data: pd.DataFrame, meta: dict, evaluator) -> pd.DataFrame:
    return measured_about(coefficients(data, meta), meta, evaluator)


def _columns(frame: pd.DataFrame, names) -> np.ndarray:
    """The columns ``names`` as one array (one column at a time: a list index costs far more)."""
    return np.column_stack([frame[c].to_numpy(dtype=float) for c in names])


def _measured_cl(data: pd.DataFrame, meta: dict, evaluator) -> np.ndarray:
    """The measured CL in the model's reference, as :func:`_measured` gives it."""
    return lift_coefficient(data, meta) * (meta["geometry"]["S_ft2"] / evaluator.S)


def model_sensitivity(
    log: Log, evaluator, noise: dict[str, float]
) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """d(model CL, CD, Cm)/d(channel) at a subsample of the log (JSBSim finite differences,
    one noise level ``noise[channel]`` up; channels the model's inputs do not see are left out),
    and the model's CL at every sample (the regressor CL, :func:`diagnose.residuals.variable_arrays`).

    Returns
    -------
    t : ndarray
        The subsample's times [s].
    sensitivity : dict
        Channel -> (len(t), 3) derivatives of CL, CD and Cm [1/channel unit].
    model_cl : ndarray
        The model's CL at each sample of the log [-].
    """
    d = log.data
    t = d["t_s"].to_numpy()
    dt = float(np.median(np.diff(t)))
    rows = np.unique(np.linspace(0, len(d) - 1, max(int((t[-1] - t[0]) / SENSITIVITY_EVERY_S), 2)).astype(int))
    ev = evaluator
    numbers = all(isinstance(k, np.dtype) and k.kind in "fiub" for k in d.dtypes)
    chans = _Channels.of(d) if numbers else d
    inputs = ev.inputs(chans, _measured_cl(chans, log.meta, ev))
    whole = ev.evaluate_array(inputs)
    base = whole[rows]
    # without inputs taken from the time series (alpha-dot, CL squared) each row's inputs are its own:
    # a perturbed channel's are made at the subsample only
    own = not ev.redirected
    at = slice(None) if own else rows
    if own:
        chans = _Channels(chans.values[rows], chans.at, chans.columns) if numbers else d.iloc[rows]
    out = {}
    for ch, sigma in noise.items():
        if ch not in d:
            continue
        if numbers:
            moved = _Channels(chans.values, chans.at, chans.columns, {ch: chans[ch].to_numpy() + sigma})
        else:
            moved = (d.iloc[rows] if own else d).copy(deep=False)  # the changed column is replaced, not written into
            moved[ch] = moved[ch] + sigma
        changed = ev.inputs(moved, None if own else _measured_cl(moved, log.meta, ev))
        if all(np.array_equal(changed[p][at], inputs[p][rows]) for p in inputs):
            continue
        out[ch] = (ev.evaluate_array(changed, None if own else rows) - base) / sigma
    return t[rows] if dt > 0 else rows.astype(float), out, whole[:, 0].copy()


def design_matrix(terms, frame: pd.DataFrame) -> np.ndarray:
    """``[1, each term's design]`` (n, 1 + widths), built in place column block by column block
    (no per-term copies to stack: the noise floor builds it for every realization). ``terms`` are
    :class:`diagnose.terms.Term` objects (anything with ``width`` and ``design(frame, out)``)."""
    x = np.empty((len(frame), 1 + sum(t.width for t in terms)))
    x[:, 0] = 1.0
    j = 1
    for t in terms:
        t.design(frame, x[:, j : j + t.width])
        j += t.width
    return x


def _chunk_sensitivity(logs: list[Log], evaluator, noise: dict[str, float]) -> list:
    return [model_sensitivity(log, evaluator, noise) for log in logs]


def model_sensitivities(logs: list[Log], evaluator, noise: dict[str, float], jobs: int = 1):
    """:func:`model_sensitivity` of every log (channels without noise left out), as a callable
    that returns them: with ``jobs`` > 1 the workers start at once and the caller goes on
    meanwhile (:func:`diagnose.evaluate.by_log_chunks`)."""
    noise = {ch: s for ch, s in noise.items() if s > 0}
    return by_log_chunks(_chunk_sensitivity, logs, evaluator, jobs, noise, wait=False)


class _Channels:
    """A log's channels by name, read as eq. (1), the variables and the model's inputs read a
    frame's (``frame[name].to_numpy()``, ``name in frame``, ``frame.columns``, ``frame.index``,
    ``len(frame)``), without a DataFrame's cost for each column read: the noise floor reads every
    log's columns for every realization and every perturbed channel.

    Parameters
    ----------
    values : ndarray
        The channels, (samples, channels).
    at : dict
        Channel name -> its column in ``values``.
    columns : Index
        The channel names, in column order.
    replaced : dict, optional
        Channel name -> values read instead of its column.
    """

    def __init__(
        self, values: np.ndarray, at: dict[str, int], columns: pd.Index, replaced: dict[str, np.ndarray] | None = None
    ) -> None:
        self.values, self.at, self.columns, self.replaced = values, at, columns, replaced or {}

    @classmethod
    def of(cls, frame: pd.DataFrame) -> _Channels:
        """A frame of numbers' channels (each column a contiguous array, as the frame's own)."""
        return cls(
            np.asfortranarray(frame.to_numpy(dtype=float)), {c: j for j, c in enumerate(frame.columns)}, frame.columns
        )

    def __len__(self) -> int:
        return len(self.values)

    def __contains__(self, name: str) -> bool:
        return name in self.at

    def __getitem__(self, name: str) -> _Column:
        x = self.replaced.get(name)
        return _Column(self.values[:, self.at[name]] if x is None else x)

    @property
    def index(self) -> pd.RangeIndex:
        return pd.RangeIndex(len(self.values))


class _Column:
    """One of :class:`_Channels`' columns (a view of its array)."""

    def __init__(self, x: np.ndarray) -> None:
        self.x = x

    def to_numpy(self, dtype=None) -> np.ndarray:
        return self.x if dtype is None else self.x.astype(dtype, copy=False)

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        return self.to_numpy(dtype)


class NoiseFloor:
    """Sizes of the diagnosis's terms fitted to instrument noise alone.

    Parameters
    ----------
    logs : list of Log
        The logs the diagnosis was fitted on (same order as its residual data).
    evaluator : ModelEvaluator
    noise : dict
        Channel -> noise level (:func:`channel_noise`).
    step : int or None
        Thinning of the residual data (None: :func:`diagnose.residuals.kept`'s default).
    realizations : int, optional
        Noise realizations (None: the settings' ``noise_realizations``, :func:`diagnose.config.current`).
    seed : int
    uncertain : (list of (channel, error), covariance), optional
        Instrument errors the data compatibility could not pin down (bias and scale
        in the channel's units, delay in s) and the covariance of their estimates:
        a second set of realizations draws them, so the floor also holds what an
        imperfect correction leaves.
    left : array, optional
        The error each of ``uncertain`` leaves in the logs as corrected, as measured (0 for one
        corrected; :meth:`identify.compat.result.CompatResult.left_in_logs`): the centre of the
        errors :meth:`reach` takes as plausible.
    unmeasured : list of (channel, error)
        Instrument errors the data compatibility could not measure at all: named
        beside a cause they could make (:meth:`reach`), with the size they would need.
    jobs : int
        Worker processes the realizations are spread over (they need no JSBSim).
    sensitivities : callable, optional
        :func:`model_sensitivities` of these logs, evaluator and noise, started earlier.
    declared : iterable of (channel, error)
        Those of ``uncertain`` that the instruments' specification bounds and the data compatibility did
        not measure (:mod:`diagnose.accuracy`): their alternatives in :meth:`reach` say so.
    """

    def __init__(
        self,
        logs: list[Log],
        evaluator,
        noise: dict[str, float],
        step: int | None = None,
        realizations: int | None = None,
        seed: int = 0,
        uncertain=None,
        unmeasured=(),
        jobs: int = 1,
        sensitivities=None,
        left=None,
        declared=(),
    ) -> None:
        self.unmeasured = list(unmeasured)  # (channel, error) the data compatibility could not measure
        self.logs, self.evaluator, self.step, self.jobs = logs, evaluator, step, jobs
        self.ref = evaluator.reference
        names, cov = uncertain if uncertain is not None else ([], np.zeros((0, 0)))
        ok = [j for j, (c, _) in enumerate(names) if cov[j, j] > 0 and any(c in lg.data for lg in logs)]
        self.uncertain = [names[j] for j in ok]
        self.uncertain_cov = cov[np.ix_(ok, ok)]
        self.uncertain_left = np.zeros(len(ok)) if left is None else np.asarray(left, float)[ok]
        self.declared = set(declared)  # (channel, error) bounded by the instruments' specification, not measured
        self.noise = {ch: s for ch, s in noise.items() if s > 0}
        self.realizations = current().noise_realizations if realizations is None else realizations
        self.seed = seed
        pending = sensitivities or model_sensitivities(logs, evaluator, self.noise, jobs)
        self._meas = [_columns(_measured(log.data, log.meta, self.ref), COEFFS) for log in logs]
        numbers = [log.data.select_dtypes("number") for log in logs]
        self._numbers = [(pd.Index(d.columns, dtype=object), d.to_numpy(dtype=float)) for d in numbers]
        self._metas = [log.meta for log in logs]
        self._sens = pending()

    def __getstate__(self) -> dict:  # to workers: no JSBSim, and the numbers only once
        return {k: v for k, v in self.__dict__.items() if k not in ("evaluator", "logs")}

    def _spread(self, method: str, items: list, *args) -> list:
        """``method(chunk, *args)`` over ``items`` in :attr:`jobs` chunks, the results joined in order."""
        return in_chunks(getattr(self, method), items, self.jobs, *args)

    def _frames(self, specs: list[dict]) -> list[pd.DataFrame]:
        """Residuals alone (no variables) of each :meth:`realization_batch` spec."""
        return self.realization_batch(set(), specs)

    def noisy(self, variables) -> bool:
        """Whether any of the variables is computed from a channel that holds noise."""
        return any(self.noise.get(ch, 0.0) > 0 for v in variables for ch in SOURCES.get(v, (v,)))

    def eiv_factors(self, variables) -> dict[str, float]:
        """How much more errors-in-variables the logs' own noise makes than the floor's realizations
        show, per variable (1 for a variable without noise, at most 2).

        A realization adds fresh noise of variance s2 to regressors that already hold noise of that
        variance, so a fit's errors-in-variables bias, which goes as s2 / (V + s2) for a regressor
        whose true values vary by V, is simulated as s2 / (V + 2 s2): the floor is low by up to
        (V + 2 s2) / (V + s2). s2 is measured as a realization's variable less the same without fresh
        noise (filtered and thinned as the regressors are), V as the variable's variance within each
        log less s2 (within a log, not across conditions: the smaller, the larger the factor).

        Parameters
        ----------
        variables : iterable of str
            Candidate variables (:data:`diagnose.residuals.VARIABLES`).
        """
        noisy = sorted(v for v in set(variables) if self.noisy([v]))
        out = {v: 1.0 for v in set(variables) if v not in noisy}
        if not noisy:
            return out
        fresh, base = self.realization_batch(set(noisy), [{"k": 0}, {"k": 0, "noise": False}])
        starts = np.cumsum([0] + [len(k) for k in self._kept()[1]])
        for v in noisy:
            x = base[v].to_numpy(float)
            s2 = float(np.nanvar(fresh[v].to_numpy(float) - x))
            within = float(
                np.nanmean(np.concatenate([x[a:b] - np.nanmean(x[a:b]) for a, b in pairwise(starts) if b > a]) ** 2)
            )
            v_true = max(within - s2, 0.0)
            out[v] = (v_true + 2.0 * s2) / (v_true + s2) if v_true + s2 > 0 else 1.0
        return out

    def realization(
        self,
        k: int,
        columns: set[str],
        noise: bool = True,
        instruments: bool = False,
        errors: np.ndarray | None = None,
        names: list | None = None,
    ) -> pd.DataFrame:
        """One residual data set made by noise alone (``noise``), by the instrument errors the
        correction may have left (``instruments``: drawn from their covariance) or by given
        ``errors`` (one per :attr:`uncertain`, or per ``names``): ``r_CL``... and the variables in
        ``columns``."""
        return self.realization_batch(
            columns, [{"k": k, "noise": noise, "instruments": instruments, "errors": errors, "names": names}]
        )[0]

    def realization_batch(self, columns: set[str], specs: list[dict]) -> list[pd.DataFrame]:
        """:meth:`realization` of each spec (its keyword arguments but ``columns``), each the same
        as alone; what they share is done once per log (the model's sensitivities at the samples,
        one spline for all their pitch accelerations)."""
        drawn = []
        for spec in specs:
            errors, names = spec.get("errors"), spec.get("names")
            if errors is None:
                errors = (
                    np.random.default_rng([self.seed, spec["k"], 10**6]).multivariate_normal(
                        np.zeros(len(self.uncertain)), self.uncertain_cov, method="eigh"
                    )
                    if spec.get("instruments") and self.uncertain
                    else np.zeros(len(self.uncertain))
                )
            drawn.append((spec["k"], spec.get("noise", True), errors, self.uncertain if names is None else names))
        dts, steps = self._kept()
        ends = np.cumsum([len(k) for k in steps])  # where each log's kept samples end in a realization
        # each realization's columns, every log's samples written in place: no per-log pieces to join
        frames: list[dict | None] = [None] * len(specs)
        for i, dt in enumerate(dts):
            cols, d = self._numbers[i]
            at = {c: j for j, c in enumerate(cols)}
            t = d[:, at["t_s"]]
            ts, sens, _ = self._sens[i]
            model = [np.column_stack([np.interp(t, ts, sj[:, j]) for j in range(len(COEFFS))]) for sj in sens.values()]
            noisy = [self._perturbed(i, d, at, t, *spec) for spec in drawn]
            qdot = (
                pitch_rate_derivative(t, np.column_stack([x[:, at["q_dps"]] for x in noisy]))
                if "qdot_dps2" not in at and noisy
                else None
            )
            lo = ends[i] - len(steps[i])
            for s, x in enumerate(noisy):
                part = self._residuals(
                    i, x, cols, at, t, dt, steps[i], model, None if qdot is None else qdot[:, s], columns
                )
                if frames[s] is None:
                    frames[s] = {c: np.empty(int(ends[-1]), dtype=v.dtype) for c, v in part.items()}
                for c, v in part.items():
                    frames[s][c][lo : ends[i]] = v
        return [pd.DataFrame(f, copy=False) if f is not None else pd.DataFrame() for f in frames]

    def _kept(self) -> tuple[list[float], list[np.ndarray]]:
        """Each log's time step [s] and the samples a realization keeps of it (:func:`diagnose.residuals.kept`)."""
        dts = [float(np.median(np.diff(d[:, cols.get_loc("t_s")]))) for cols, d in self._numbers]
        return dts, [kept(len(d), dt, self.step) for (_, d), dt in zip(self._numbers, dts)]

    def _perturbed(self, i: int, d: np.ndarray, at: dict, t: np.ndarray, k: int, noise: bool, errors, names):
        """Log ``i``'s channels with realization ``k``'s noise (if ``noise``) and the instrument errors."""
        chans = [at[ch] for ch in sorted(self.noise) if ch in at]
        noisy = d.copy()
        if noise:
            rng = np.random.default_rng([self.seed, k, i])
            noisy[:, chans] = d[:, chans] + rng.standard_normal((len(d), len(chans))) * np.array(
                [self.noise[self._numbers[i][0][j]] for j in chans]
            )
        for (c, e), z in zip(names, errors):  # the same instrument error in every log
            if c in at and z:
                x = noisy[:, at[c]].copy()
                noisy[:, at[c]] = x + z if e == "bias" else x * (1 + z) if e == "scale" else np.interp(t - z, t, x)
        return noisy

    def _residuals(
        self,
        i: int,
        noisy: np.ndarray,
        cols,
        at: dict,
        t: np.ndarray,
        dt: float,
        keep: np.ndarray,
        model: list[np.ndarray],
        qdot: np.ndarray | None,
        columns: set[str],
    ) -> dict[str, np.ndarray]:
        """Log ``i``'s residuals and variables from its perturbed channels, filtered and thinned."""
        meta, d = self._metas[i], self._numbers[i][1]
        moved = noisy[:, [at[c] for c in self._sens[i][1]]] - d[:, [at[c] for c in self._sens[i][1]]]
        frame = _Channels(noisy, at, cols)
        meas = measured_arrays(coefficient_arrays(frame, meta, qdot), meta, self.ref)
        r = np.column_stack([meas[c] for c in COEFFS]) - self._meas[i]
        model_cl = self._sens[i][2].copy()
        for m, at_samples in enumerate(model):  # the model's answer to the changed channels, linearised
            r = r - at_samples * moved[:, [m]]
            model_cl += at_samples[:, 0] * moved[:, m]
        out = dict(zip((f"r_{c}" for c in COEFFS), lowpass(r, dt)[keep].T))
        var = variable_arrays(frame, meta, model_cl, sorted(columns))
        sig = [c for c in columns if c.startswith("thrust_")]
        if sig:
            shares = signature_arrays(frame, meta, self.ref)
            var.update((c, shares[c]) for c in sig)
        smoothed = [v for v in var if v in FILTERED or v in sig]
        if smoothed:
            out.update(zip(smoothed, lowpass(np.array([var[v] for v in smoothed], dtype=float).T, dt)[keep].T))
        out.update((v, x[keep]) for v, x in var.items() if v not in out)
        return out

    def sizes(self, groups: list[tuple[str, list]], instruments: bool = False) -> list[np.ndarray]:
        """For each (coefficient, terms) group: its size fitted to each realization of noise
        alone, or (``instruments``) of the correction's remaining instrument errors alone
        (drawn at random; :meth:`reach` asks instead what they can make of a given shape).

        ``terms`` are :class:`diagnose.terms.Term` objects (anything with ``variables`` and ``design``).
        The size is the range (max - min) of the fitted contribution over the data.
        """
        columns = {v for _, terms in groups for t in terms for v in t.variables}
        if instruments and not self.uncertain:
            return [np.zeros(0) for _ in groups]
        sizes = np.array(self._spread("_sizes", list(range(self.realizations)), groups, columns, instruments))
        return [sizes[:, g].copy() for g in range(len(groups))] if len(sizes) else [np.zeros(0) for _ in groups]

    def _sizes(
        self, ks: list[int], groups: list[tuple[str, list]], columns: set[str], instruments: bool
    ) -> list[list[float]]:
        out = []
        for batch in (ks[j : j + REALIZATION_BATCH] for j in range(0, len(ks), REALIZATION_BATCH)):
            for frame in self.realization_batch(
                columns, [{"k": k, "noise": not instruments, "instruments": instruments} for k in batch]
            ):
                row = [0.0] * len(groups)
                shared: dict[tuple, list[int]] = {}  # coefficients with the same terms share the design
                for g, (_, terms) in enumerate(groups):
                    shared.setdefault(tuple(map(id, terms)), []).append(g)
                for same in shared.values():  # one design held at a time, its columns scaled in place
                    x = design_matrix(groups[same[0]][1], frame)
                    scale = np.linalg.norm(x, axis=0)
                    scale[scale == 0] = 1.0
                    x /= scale
                    gram = x.T @ x
                    for g in same:
                        beta = solve_normal(gram, x.T @ frame[f"r_{groups[g][0]}"].to_numpy())
                        row[g] = float(np.ptp(x[:, 1:] @ beta[1:]))
                    del x
                out.append(row)
        return out

    def channel_left_se(self, channel: str) -> float:
        """How far the errors of one channel the logs still hold as measured (:attr:`uncertain_left`) are,
        together, from none: the Mahalanobis distance in their joint covariance [standard errors]. A vane's
        bias and scale, confounded over the few trim alphas flown, can each be short of 2 standard errors
        of none and the vane's offset over those alphas many."""
        j = [i for i, (ch, _) in enumerate(self.uncertain) if ch == channel]
        if not j:
            return 0.0
        v = self.uncertain_left[j]
        return float(np.sqrt(max(float(v @ np.linalg.pinv(self.uncertain_cov[np.ix_(j, j)]) @ v), 0.0)))

    def instrument_axes(self) -> np.ndarray:
        """The principal axes of the remaining instrument errors' covariance, one standard error
        long (columns, in channel units)."""
        if not self.uncertain:
            return np.zeros((0, 0))
        w, v = np.linalg.eigh(self.uncertain_cov)
        keep = w > 1e-12 * max(float(w.max()), 1e-300)
        return v[:, keep] * np.sqrt(w[keep])

    def reach(
        self,
        causes: list[tuple[str, list, np.ndarray]],
        data: pd.DataFrame,
        radius: float | None = None,
        weights=None,
        beside: dict | None = None,
    ) -> list[dict]:
        """What the remaining instrument errors can make of each cause's fitted shape.

        For a cause on coefficient ``c`` with terms ``T`` and fitted contribution ``f``
        over ``data``, the residuals the instrument errors make are seen through ``T``
        (projected on its span, as a fit would see them), and the errors within
        ``radius`` standard errors (Mahalanobis, the data compatibility's covariance; None: the
        settings' ``reach_se``, :func:`diagnose.config.current`)
        that come closest to ``f`` are found (a trust-region least-squares problem, centred at the
        errors the logs still hold as measured, :attr:`uncertain_left`). The
        part of ``f`` left is what no plausible instrument error can make. With ``weights`` (one
        over each coefficient's noise per effective sample, CL, CD, Cm) the errors must also fit
        the other coefficients' residuals, each weighted so: an error that would make the cause
        but leave in CD or Cm a signature the data do not hold cannot make it. ``beside`` (the terms
        fitted to each coefficient): the other coefficients' residuals and signatures are taken beside
        their own terms, so that an error may share another coefficient's residual with the aero
        terms fitted there (a vane scale under-corrected leaves a Cm in alpha, and a CL effect in
        alpha beside it made the CL residual seem to refuse the scale). Each
        instrument error alone, at any size, is also fitted to ``f``: the alternatives
        that make most of it, with the size they would need.

        Returns
        -------
        list of dict
            Per cause: ``made`` and ``left`` (ranges of what the plausible instrument
            errors make of it and of the rest), ``alternatives`` (channel, error, the
            size needed in the channel's units and in standard errors from what the logs hold as
            measured, the share of the cause's variance it explains [%]), best first.
        """
        radius = current().reach_se if radius is None else radius
        unit = {"delay": 0.01, "scale": 0.01, "bias": 0.1}
        shown = [(ch, e) for ch, e in self.unmeasured if any(ch in lg.data for lg in self.logs)]
        axes = self.instrument_axes()
        # the residuals along each axis and of each unmeasured error, in one spread over the workers
        specs = [{"k": 0, "noise": False, "errors": a} for a in axes.T] + [
            {"k": 0, "noise": False, "errors": np.array([unit[e]]), "names": [(ch, e)]} for ch, e in shown
        ]
        frames = self._spread("_frames", specs) if specs else []
        resp = frames[: axes.shape[1]]
        se = np.sqrt(np.diag(self.uncertain_cov)) if resp else np.zeros(0)
        to_axes = np.linalg.pinv(axes) if resp else np.zeros((0, 0))
        blind = [(ch, e, r) for (ch, e), r in zip(shown, frames[axes.shape[1] :])]
        out = []
        for c, terms, f in causes:
            f = np.asarray(f, float) - np.mean(f)
            ff = float(f @ f)
            x = design_matrix(terms, data)

            def through_terms(cols: np.ndarray, x: np.ndarray = x) -> np.ndarray:
                seen = x @ np.linalg.lstsq(x, cols, rcond=None)[0]
                return seen - seen.mean(axis=0)

            def alone(one: np.ndarray, f: np.ndarray = f, ff: float = ff) -> tuple[float, float]:
                nn = float(one @ one)
                if nn <= 0 or ff <= 0:
                    return 0.0, -np.inf
                k = float(one @ f) / nn
                return k, 100.0 * (1.0 - float((f - k * one) @ (f - k * one)) / ff)

            alts, made = [], np.zeros(len(f))
            if resp:
                assert all(len(r) == len(data) for r in resp)
                seen = through_terms(np.column_stack([r[f"r_{c}"].to_numpy() for r in resp]))
                a, b = seen, f
                if weights is not None:
                    w = dict(zip(COEFFS, weights))
                    a, b = [w[c] * seen], [w[c] * f]
                    for o in COEFFS:
                        if o != c and w[o] > 0:
                            cols = np.column_stack([r[f"r_{o}"].to_numpy() for r in resp])
                            y = data[f"r_{o}"].to_numpy(float)
                            ok = np.isfinite(y) & np.isfinite(cols).all(axis=1)
                            cols = np.where(ok[:, None], cols - cols[ok].mean(axis=0), 0.0)
                            y = np.where(ok, y - y[ok].mean(), 0.0)
                            if beside and beside.get(o):
                                xo = design_matrix(beside[o], data)
                                xo = np.where(ok[:, None], xo - xo[ok].mean(axis=0), 0.0)
                                cols, y = (v - xo @ np.linalg.lstsq(xo, v, rcond=None)[0] for v in (cols, y))
                            a.append(w[o] * cols)
                            b.append(w[o] * y)
                    a, b = np.vstack(a), np.concatenate(b)
                z0 = to_axes @ self.uncertain_left
                made = seen @ (z0 + _trust_region(a, b - a @ z0, radius))
                for j, (ch, err) in enumerate(self.uncertain):
                    k, share = alone(seen @ to_axes[:, j] * se[j])  # one standard error of this error alone
                    left = float(self.uncertain_left[j])
                    alts.append(
                        {
                            "channel": ch,
                            "error": err,
                            "needs": k * se[j],
                            "needs_se": k - left / se[j],
                            "se": float(se[j]),
                            "left": left,
                            "explains_pct": share,
                            "channel_left_se": self.channel_left_se(ch),
                            **({"declared": True} if (ch, err) in self.declared else {}),
                        }
                    )
            for ch, err, r in blind:  # errors the data compatibility could not measure: no standard error
                k, share = alone(through_terms(r[f"r_{c}"].to_numpy()[:, None])[:, 0])
                alts.append(
                    {
                        "channel": ch,
                        "error": err,
                        "needs": k * unit[err],
                        "needs_se": 0.0,
                        "se": float("nan"),
                        "explains_pct": share,
                        "unmeasured": True,
                    }
                )
            alts.sort(key=lambda a: -a["explains_pct"])
            out.append({"made": float(np.ptp(made)), "left": float(np.ptp(f - made)), "alternatives": alts})
        return out


def _trust_region(a: np.ndarray, b: np.ndarray, radius: float) -> np.ndarray:
    """``argmin |a z - b|`` subject to ``|z| <= radius``."""
    from scipy.optimize import brentq

    u, s, vt = np.linalg.svd(a, full_matrices=False)
    keep = s > 1e-10 * max(float(s.max(initial=0.0)), 1e-300)
    u, s, vt = u[:, keep], s[keep], vt[keep]
    ub = u.T @ b

    def z(lam: float) -> np.ndarray:
        return vt.T @ (s * ub / (s**2 + lam))

    if not len(s) or np.linalg.norm(z(0.0)) <= radius:
        return z(0.0) if len(s) else np.zeros(a.shape[1])
    hi = float(s.max() * np.linalg.norm(ub) / radius)
    lam = brentq(lambda lam: np.linalg.norm(z(lam)) - radius, 0.0, hi * 1.01 + 1e-300)
    return z(lam)
