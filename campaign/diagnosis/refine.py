"""``campaign diagnose --refine oe``: the extension's terms refined by output error through JSBSim.

The equation-error extension fits the coefficient residuals. Output error asks instead what
makes the aeroplane fly like the data: each term of the extension gets a scale (1 to start),
the fitted logs where the first cause acts are replayed on the model extended with the scaled
terms (same trimmed start, recorded inputs, the measured wind), and the scales minimize ``det(R)`` of the replay
errors in theta, alpha, q and airspeed (:class:`identify.estimators.OutputError`, sensitivities
by finite differences: one replay set per term per iteration). The refined extension is then
measured on the held-out logs like the equation-error one.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from campaign.simulation.aircraft import AircraftSource, load_effects
from diagnose.evaluate import ModelEvaluator
from diagnose.extension import aero_terms, scaled, term_name, write_extension
from diagnose.gain import exercised, measure_gain, on_log_times
from diagnose.residuals import residual_data
from diagnose.result import Diagnosis
from identify.estimators import OutputError, Record, StateSpaceModel
from identify.export import merge_into_aircraft
from identify.kinematics import measured_wind
from identify.logs import Log
from infra.pool import pmap

REFINE = ("oe",)
CHANNELS = ("theta_deg", "alpha_deg", "q_dps", "tas_kt")
#: At most this many fitted logs are replayed per parameter vector (those with the largest residual).
MAX_LOGS = 4
#: Above this vertical gust in the data compatibility's reconstruction [ft/s RMS], replays in
#: still air cannot follow the data: the refinement says so when a fitted log has no measured wind.
TURBULENT_FPS = 0.5


class ReplayOutputError(OutputError):
    """Output error whose model is a JSBSim aircraft built from the scaled extension.

    Parameters
    ----------
    diag : Diagnosis
    model : Path
        The model aircraft folder the extension is merged into.
    logs : list of Log
        The fitted logs (as corrected).
    work : Path
        Scratch folder for the trial aircraft.
    replay : callable
        ``replay(log, source) -> DataFrame or None`` (:func:`campaign.diagnosis.run.replay`).
    jobs : int
    """

    batched_trials = False  # each trial is an aircraft built and flown: a batch costs what its trials cost

    def __init__(
        self,
        diag: Diagnosis,
        model: Path,
        logs: list[Log],
        work: Path,
        replay,
        jobs: int = 1,
        max_iter: int = 8,
        tol: float = 1e-3,
    ) -> None:
        self.diag, self.model_dir, self.logs, self.work, self.replay, self.jobs = diag, model, logs, work, replay, jobs
        self.terms = [term_name(c, i, t) for c, i, t in aero_terms(diag)]
        self._sources: dict[tuple, AircraftSource] = {}
        self.times = [lg.data["t_s"].to_numpy() for lg in logs]
        records = [
            Record(
                np.zeros((len(lg.data), 1)),
                lg.data[list(CHANNELS)].to_numpy(dtype=float),
                float(np.median(np.diff(lg.data.t_s))),
                np.zeros(0),
                name=Path(lg.path).stem,
            )
            for lg in logs
        ]
        shell = StateSpaceModel(None, None, (), ("none",), CHANNELS, tuple(self.terms))
        super().__init__(shell, records, np.ones(len(self.terms)), tol=tol, max_iter=max_iter, step=0.02)
        # compare over what the unrefined extension's replay flies of each log
        first = self.predict(np.ones((1, len(self.terms))))
        kept = [
            (r, t[:n])
            for r, t, y in zip(self.records, self.times, first)
            if (n := int(np.argmax(np.append(np.isnan(y[0, :, 0]), True)))) > 1
        ]
        self.records = [Record(r.u[: len(t)], r.z[: len(t)], r.dt_s, r.x0, name=r.name) for r, t in kept]
        self.times = [t for _, t in kept]
        self.logs = [lg for lg in self.logs if Path(lg.path).stem in {r.name for r in self.records}]
        if not self.records:
            raise ValueError("no fitted log could be replayed on the extended model")

    def source(self, scales: np.ndarray) -> AircraftSource:
        """The model extended with the terms scaled (built once per scale vector)."""
        key = tuple(np.round(scales, 12))
        if key not in self._sources:
            folder = self.work / f"trial{len(self._sources)}"
            folder.mkdir(parents=True)
            xml = write_extension(scaled(self.diag, dict(zip(self.terms, scales))), folder / "extension.xml")
            aircraft = merge_into_aircraft(self.model_dir, xml, folder / "aircraft", replace_gear=False)
            self._sources[key] = AircraftSource(str(aircraft), load_effects(None))
        return self._sources[key]

    def predict(self, thetas: np.ndarray) -> list[np.ndarray]:
        p, _, biases = self._unpack(thetas)
        sources = [self.source(row) for row in p]
        flown = pmap(self.replay, [(lg, src) for src in sources for lg in self.logs], self.jobs)
        out = []
        for j, rec in enumerate(self.records):
            y = np.full((len(p), rec.n, len(CHANNELS)), np.nan)
            for b in range(len(p)):
                frame = flown[b * len(self.logs) + j]
                if frame is not None:
                    y[b] = on_log_times(frame, self.times[j], CHANNELS)
            out.append(y + biases[j][:, None, :])
        return out


def fitted_logs(diag: Diagnosis) -> list[Log]:
    """The training logs where the first aerodynamic cause acts, at most :data:`MAX_LOGS` of them
    (the largest residual RMS of its coefficient first)."""
    cause = diag.aero_causes[0]
    acting = exercised(diag.data, cause.variables, diag.settings.min_std)
    col = f"r_{cause.coefficient}"
    rms = diag.data[diag.data.log.isin(acting)].groupby("log")[col].agg(lambda r: float(np.sqrt(np.mean(r**2))))
    return [diag.logs[int(i)] for i in rms.sort_values(ascending=False).index[:MAX_LOGS]]


def refine_extension(
    diag: Diagnosis,
    model: Path,
    out: Path,
    held: list[Log],
    before: pd.DataFrame,
    flown_model: dict[str, pd.DataFrame | None],
    replay,
    jobs: int = 1,
) -> dict:
    """Refine the extension by output error, write it beside the equation-error one, measure its gain.

    Returns
    -------
    dict
        What ``diagnosis.json`` holds under ``refine``: the method, the fitted logs, each term's
        scale with its Cramér-Rao and coloured bounds, convergence, the files, and ``gain``
        (:func:`diagnose.gain.measure_gain` of the refined extension).
    """
    work = out / ".refine"
    logs = fitted_logs(diag)
    gust = diag.compat.turbulence_fps if diag.compat is not None else None
    try:
        est = ReplayOutputError(diag, model, logs, work, replay, jobs)
        res = est.fit()
    except (ValueError, np.linalg.LinAlgError) as exc:  # no replay flew, or a term the replays cannot see
        return {"method": "oe", "error": str(exc), "fitted_logs": [Path(lg.path).name for lg in logs]}
    finally:
        shutil.rmtree(work, ignore_errors=True)
    scales = dict(zip(est.terms, res.params.to_numpy()))
    refined = scaled(diag, scales)
    xml = write_extension(refined, out / "extension_oe.xml")
    folder = merge_into_aircraft(model, xml, out / "extended_aircraft_oe", replace_gear=False)
    evaluator = ModelEvaluator(folder, jobs=jobs)
    try:
        after = residual_data(held, evaluator)
    finally:
        evaluator.close()
    src = AircraftSource(str(folder), load_effects(None))
    flown_new = pmap(replay, [(lg, src) for lg in held], jobs)
    flown = {lg.path: (flown_model[lg.path], f) for lg, f in zip(held, flown_new)}
    caveat = None
    still = [Path(lg.path).name for lg in logs if measured_wind(lg.data) is None]
    if gust is not None and gust > TURBULENT_FPS and still:
        caveat = (
            f"the data were flown in turbulence (vertical gust {gust:.2g} ft/s RMS in the reconstruction) and "
            f"{len(still)} fitted logs have no inertial velocity, so their replays fly in still air: the gusts "
            "are replay errors the scales are bent to reduce; trust the equation-error extension"
        )
    return {
        "method": "oe",
        "caveat": caveat,
        "fitted_logs": [Path(lg.path).name for lg in logs],
        "scales": scales,
        "se": dict(zip(est.terms, res.bse.to_numpy())),
        "se_coloured": dict(zip(est.terms, res.bse_coloured.to_numpy())),
        "iterations": res.iterations,
        "converged": res.converged,
        "replay_residual_std": {k: float(np.sqrt(v)) for k, v in res.R.items()},
        "extension": str(folder),
        "extension_xml": str(xml),
        "gain": measure_gain(refined, held, before, after, flown),
    }
