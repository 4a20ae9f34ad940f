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

import numpy as np
import pandas as pd

from identify.coefficients import coefficients
from identify.logs import Log
from identify.models import EDGE_S, lowpass
from identify.residuals import COEFFS, FILTERED, measured_about, variables

#: Channels whose sensor noise reaches the residuals or the regressors.
NOISY = ("alt_ft", "tas_kt", "mach", "alpha_deg", "beta_deg", "theta_deg", "phi_deg", "p_dps", "q_dps", "r_dps",
         "qdot_dps2", "ax_fps2", "ay_fps2", "az_fps2", "qbar_psf", "thrust_lbf", "elevator_deg",
         "stabilizer_deg", "flap_deg", "gear_norm", "mass_slug")
#: The channels each candidate variable is computed from (errors-in-variables needs noise in one).
SOURCES = {"gear_norm": ("gear_norm",), "alpha_deg": ("alpha_deg",), "mach": ("mach",), "flap_deg": ("flap_deg",),
           "elevator_deg": ("elevator_deg",), "stabilizer_deg": ("stabilizer_deg",),
           "qhat_rad": ("q_dps", "tas_kt"),
           "adothat_rad": ("alpha_deg", "beta_deg", "tas_kt", "ax_fps2", "az_fps2", "p_dps", "q_dps", "r_dps",
                           "theta_deg", "phi_deg"),
           "CL": ("ax_fps2", "az_fps2", "alpha_deg", "qbar_psf", "thrust_lbf", "mass_slug")}
SENSITIVITY_EVERY_S = 0.5
#: Below this a coefficient change is beyond the evaluation's own resolution (it reproduces
#: noise-free logs to about 1e-7).
RESOLUTION = 1e-5


def channel_noise(logs: list[Log]) -> dict[str, float]:
    """White-noise level (1 sigma) of each channel, in its own units.

    From the second differences, which a smooth signal sampled fast hardly
    feeds: ``1.4826 MAD(d2x) / sqrt(6)`` per log (robust to steps and
    spikes), the median over the logs.
    """
    out = {}
    for ch in NOISY:
        levels = []
        for log in logs:
            if ch in log.data:
                d2 = np.diff(log.data[ch].to_numpy(dtype=float), 2)
                if len(d2):
                    levels.append(1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / np.sqrt(6.0))
        if levels:
            out[ch] = float(np.median(levels))
    return out


def _measured(data: pd.DataFrame, meta: dict, evaluator) -> pd.DataFrame:
    return measured_about(coefficients(data, meta), meta, evaluator)


class NoiseFloor:
    """Sizes of the diagnosis's terms fitted to instrument noise alone.

    Parameters
    ----------
    logs : list of Log
        The logs the diagnosis was fitted on (same order as its residual data).
    evaluator : ModelEvaluator
    noise : dict
        Channel -> noise level (:func:`channel_noise`).
    step : int
        Thinning of the residual data.
    realizations : int
    seed : int
    """

    def __init__(self, logs: list[Log], evaluator, noise: dict[str, float], step: int = 2,
                 realizations: int = 20, seed: int = 0) -> None:
        self.logs, self.evaluator, self.step = logs, evaluator, step
        self.noise = {ch: s for ch, s in noise.items() if s > 0}
        self.realizations, self.seed = realizations, seed
        self._sens = [self._model_sensitivity(log) for log in logs]
        self._meas = [_measured(log.data, log.meta, evaluator) for log in logs]

    def _model_sensitivity(self, log: Log) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """d(model CL, CD, Cm)/d(channel) at a subsample of the log (JSBSim finite differences)."""
        d = log.data
        t = d["t_s"].to_numpy()
        dt = float(np.median(np.diff(t)))
        rows = np.unique(np.linspace(0, len(d) - 1, max(int((t[-1] - t[0]) / SENSITIVITY_EVERY_S), 2)).astype(int))
        ev = self.evaluator
        base = ev.evaluate(ev.inputs(d, _measured(d, log.meta, ev)["CL"].to_numpy()), rows).to_numpy()
        out = {}
        for ch, sigma in self.noise.items():
            if ch not in d:
                continue
            moved = d.copy()
            moved[ch] = moved[ch] + sigma
            cl = _measured(moved, log.meta, ev)["CL"].to_numpy()
            out[ch] = (ev.evaluate(ev.inputs(moved, cl), rows).to_numpy() - base) / sigma
        return t[rows] if dt > 0 else rows.astype(float), out

    def noisy(self, variables) -> bool:
        """Whether any of the variables is computed from a channel that holds noise."""
        return any(self.noise.get(ch, 0.0) > 0 for v in variables for ch in SOURCES.get(v, (v,)))

    def realization(self, k: int, columns: set[str]) -> pd.DataFrame:
        """One noise-only residual data set: ``r_CL``... and the variables in ``columns``."""
        frames = []
        for i, log in enumerate(self.logs):
            d = log.data
            t = d["t_s"].to_numpy()
            dt = float(np.median(np.diff(t)))
            rng = np.random.default_rng([self.seed, k, i])
            chans = [ch for ch in sorted(self.noise) if ch in d]
            draws = rng.standard_normal((len(d), len(chans))) * np.array([self.noise[ch] for ch in chans])
            noisy = d.copy()
            noisy[chans] = d[chans].to_numpy() + draws
            meas = _measured(noisy, log.meta, self.evaluator)
            ts, sens = self._sens[i]
            edge = int(round(EDGE_S / dt))
            keep = np.arange(edge, len(d) - edge, self.step)
            out = {}
            for j, c in enumerate(COEFFS):
                r = meas[c].to_numpy() - self._meas[i][c].to_numpy()
                for ch, sj in sens.items():
                    r = r - np.interp(t, ts, sj[:, j]) * draws[:, chans.index(ch)]
                out[f"r_{c}"] = lowpass(r, dt)[keep]
            var = variables(noisy, log.meta, meas["CL"].to_numpy(), sorted(columns))
            for v in var.columns:
                x = var[v].to_numpy()
                out[v] = (lowpass(x, dt) if v in FILTERED else x)[keep]
            frames.append(pd.DataFrame(out))
        return pd.concat(frames, ignore_index=True)

    def sizes(self, groups: list[tuple[str, list]]) -> list[np.ndarray]:
        """For each (coefficient, terms) group: its size fitted to each noise realization.

        ``terms`` are :class:`identify.diagnosis.Term` objects (anything with ``variables`` and ``design``).

        The size is the range (max - min) of the fitted contribution over the data.
        """
        columns = {v for _, terms in groups for t in terms for v in t.variables}
        out = [np.empty(self.realizations) for _ in groups]
        for k in range(self.realizations):
            frame = self.realization(k, columns)
            for g, (c, terms) in enumerate(groups):
                x = np.column_stack([np.ones(len(frame))] + [t.design(frame) for t in terms])
                beta, *_ = np.linalg.lstsq(x, frame[f"r_{c}"].to_numpy(), rcond=None)
                contrib = x[:, 1:] @ beta[1:]
                out[g][k] = float(np.ptp(contrib))
        return out
