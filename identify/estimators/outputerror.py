"""Output-error estimation: maximum likelihood for measurement noise only.

The model is integrated from its initial states with the measured inputs; the parameters
minimize ``det(R)``, ``R`` the covariance of the output residuals, by the relaxation of
Jategaonkar (2015, ch. 4): ``R`` in closed form, then a Gauss-Newton step on the parameters
with ``R`` held (the parameters scaled to a unit diagonal of the information matrix), the step
halved while the cost rises. Sensitivities are forward
differences, integrated as one batch with the nominal model.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence

import numpy as np
import pandas as pd

from identify.estimators.dynamics import Record, StateSpaceModel, simulate
from identify.estimators.results import TimeDomainResults
from identify.lsq import lagged_gram


#: A fit has converged when a step moves no estimate by more than this share of its Cramér-Rao bound
#: (or changes the cost by less than the tolerance).
STILL_SE = 0.1


def bounds(m: np.ndarray) -> np.ndarray:
    """Cramér-Rao bounds of an information matrix (scaled before it is inverted)."""
    d = np.sqrt(np.clip(np.diag(m), 1e-300, None))
    return np.sqrt(np.clip(np.diag(np.linalg.pinv(m / np.outer(d, d))), 1e-300, None)) / d


def solve_scaled(m: np.ndarray, g: np.ndarray) -> np.ndarray:
    """The Gauss-Newton step ``m^-1 g``, ``m`` scaled to a unit diagonal first (parameters of
    very different sizes: a lift slope, a pitch damping, a process-noise level), by least
    squares if it is singular (a parameter the data do not determine stays put)."""
    d = np.sqrt(np.clip(np.diag(m), 1e-300, None))
    ms = m / np.outer(d, d)
    try:
        return np.linalg.solve(ms, g / d) / d
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(ms, g / d, rcond=1e-12)[0] / d


class OutputError:
    """Output-error estimator for one model over one or several records.

    Parameters
    ----------
    model : StateSpaceModel
    records : sequence of Record
        Fitted together: the model's parameters are shared, initial states and output
        biases are per record.
    p0 : mapping or array_like
        Starting values of the model's parameters (all of them; fixed ones keep theirs).
    free : collection of str, optional
        The model parameters to estimate; None: all.
    x0_free : collection of str
        States whose initial value is estimated, per record.
    biases : collection of str
        Outputs with an estimated bias, per record.
    tol : float
        Convergence: relative change of ``det(R)`` between iterations (or a step that moves no
        estimate by more than :data:`STILL_SE` of its Cramér-Rao bound).
    max_iter : int
    step : float
        Relative finite-difference step (absolute for parameters at zero).
    """

    method = "oe"
    #: Whether a line search's trials are simulated as one batch (:meth:`_line_search`): where ``predict`` is
    #: this class's numpy simulation, which costs the same for one parameter vector as for a dozen. A subclass
    #: whose ``predict`` costs per vector (JSBSim replays) or whose objective keeps state sets it False.
    batched_trials = True

    def __init__(
        self,
        model: StateSpaceModel,
        records: Sequence[Record],
        p0,
        free: Collection[str] | None = None,
        x0_free: Collection[str] = (),
        biases: Collection[str] = (),
        tol: float = 1e-5,
        max_iter: int = 50,
        step: float = 1e-4,
    ) -> None:
        self.model = model
        self.records = list(records)
        p0 = np.array([p0[k] for k in model.params] if isinstance(p0, Mapping) else p0, dtype=float)
        if p0.shape != (len(model.params),):
            raise ValueError(f"p0 has {p0.size} values for {len(model.params)} parameters")
        self.p_fixed = p0
        free = model.params if free is None else tuple(free)
        unknown = set(free) - set(model.params) | set(x0_free) - set(model.states) | set(biases) - set(model.outputs)
        if unknown:
            raise ValueError(f"unknown names: {sorted(unknown)}")
        self.i_free = [model.params.index(k) for k in free]
        self.i_x0 = [model.states.index(k) for k in x0_free]
        self.i_bias = [model.outputs.index(k) for k in biases]
        self.tol, self.max_iter, self.step = tol, max_iter, step
        self.names = list(free)
        for r in self.records:
            self.names += [f"x0[{r.name}].{model.states[i]}" for i in self.i_x0]
        for r in self.records:
            self.names += [f"bias[{r.name}].{model.outputs[i]}" for i in self.i_bias]

    def _start(self) -> np.ndarray:
        theta = list(self.p_fixed[self.i_free])
        for r in self.records:
            theta += list(r.x0[self.i_x0])
        for r in self.records:
            theta += [0.0] * len(self.i_bias)
        return np.array(theta)

    def _unpack(self, thetas: np.ndarray) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
        """Model parameters (B, np), initial states per record (B, nx), output biases per record (B, ny)."""
        nb, nf, nx0, nbias = len(thetas), len(self.i_free), len(self.i_x0), len(self.i_bias)
        p = np.repeat(self.p_fixed[None], nb, axis=0)
        p[:, self.i_free] = thetas[:, :nf]
        x0s, biases = [], []
        for j, r in enumerate(self.records):
            x0 = np.repeat(r.x0[None], nb, axis=0)
            x0[:, self.i_x0] = thetas[:, nf + j * nx0 : nf + (j + 1) * nx0]
            x0s.append(x0)
            b = np.zeros((nb, len(self.model.outputs)))
            k = nf + len(self.records) * nx0 + j * nbias
            b[:, self.i_bias] = thetas[:, k : k + nbias]
            biases.append(b)
        return p, x0s, biases

    def predict(self, thetas: np.ndarray) -> list[np.ndarray]:
        """Model outputs per record, shape (B, N, ny), for a batch of parameter vectors."""
        p, x0s, biases = self._unpack(thetas)
        return [simulate(self.model, p, x0, r) + b[:, None, :] for r, x0, b in zip(self.records, x0s, biases)]

    def _residuals(self, theta: np.ndarray) -> list[np.ndarray]:
        return [r.z - y[0] for r, y in zip(self.records, self.predict(theta[None]))]

    def _sensitivities(self, theta: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Residuals and output sensitivities ``dy/dtheta`` (N, ny, n) per record; an output bias's is
        one on its record's output, the others' are finite differences."""
        n, first = len(theta), len(self.i_free) + len(self.records) * len(self.i_x0)
        nbias = len(self.records) * len(self.i_bias)
        moved = [i for i in range(n) if not first <= i < first + nbias]
        h = np.where(theta != 0.0, self.step * np.abs(theta), self.step)[moved]
        batch = np.repeat(theta[None], len(moved) + 1, axis=0)
        batch[1 + np.arange(len(moved)), moved] += h
        ys = self.predict(batch)
        res = [r.z - y[0] for r, y in zip(self.records, ys)]
        sens = []
        for j, y in enumerate(ys):
            s = np.zeros((y.shape[1], y.shape[2], n))
            s[:, :, moved] = np.transpose((y[1:] - y[:1]) / h[:, None, None], (1, 2, 0))
            for k, out in enumerate(self.i_bias):
                s[:, out, first + j * len(self.i_bias) + k] = 1.0
            sens.append(s)
        return res, sens

    @staticmethod
    def _covariance(res: list[np.ndarray]) -> np.ndarray:
        stacked = np.vstack(res)
        return np.mean(stacked**2, axis=0)

    def _prepare(self, theta: np.ndarray) -> None:
        """Hook run before each iteration's sensitivities (the filter error updates its gains)."""

    def _constrain(self, theta: np.ndarray, delta: np.ndarray, m: np.ndarray, g: np.ndarray) -> np.ndarray:
        """Hook: the step under the estimator's constraints (none for the output error)."""
        return delta

    def _trial_ok(self, trial: np.ndarray) -> bool:
        """Hook: whether a trial step keeps the estimator's constraints (always, for the output error)."""
        return True

    def _line_search(
        self, theta: np.ndarray, delta: np.ndarray, cost: float, halvings: int
    ) -> tuple[np.ndarray, float, np.ndarray] | None:
        """The first of ``theta + delta``, ``theta + delta / 2``, ... that lowers the cost and keeps the
        constraints: (parameters, cost, R), or None. Where the objective keeps no state
        (:attr:`batched_trials`) the trials are simulated together, as one batch: a simulation's cost is
        its steps', the same for one parameter vector as for a dozen (numpy's call overhead), and each
        trial's outputs are those it has alone, bit for bit."""
        trials = theta + np.array([delta * 0.5**k for k in range(halvings)])
        if self.batched_trials:
            ys = self.predict(trials)
            costs = (self._cost([rec.z - y[b] for rec, y in zip(self.records, ys)]) for b in range(halvings))
        else:
            costs = (self._objective(trial) for trial in trials)
        for trial, (c, r) in zip(trials, costs):
            if np.isfinite(c) and c <= cost and self._trial_ok(trial):
                return trial, c, r
        return None

    def _stalled(self, theta: np.ndarray, iteration: int, cost: float, r: np.ndarray):
        """Hook where no step lowers the cost: the parameters, cost and ``R`` to go on from if the
        estimator can still lower it otherwise; True if it has converged; False to judge by the steps
        taken (the output error: ``R`` is in closed form)."""
        return False

    def _objective(self, theta: np.ndarray) -> tuple[float, np.ndarray]:
        """The cost minimized, ``log det R`` with ``R`` the residuals' covariance (diagonal), and that ``R``."""
        return self._cost(self._residuals(theta))

    def _cost(self, res: list[np.ndarray]) -> tuple[float, np.ndarray]:
        """:meth:`_objective` of the residuals ``res`` (one array per record)."""
        r = self._covariance(res)
        return float(np.sum(np.log(r))), r

    def _after_step(
        self, theta: np.ndarray, iteration: int, cost: float, r: np.ndarray
    ) -> tuple[np.ndarray, float, np.ndarray]:
        """Hook after an accepted step: the parameters, the cost and ``R`` to go on from."""
        return theta, cost, r

    def _information(self, res, sens, w) -> tuple[np.ndarray, np.ndarray]:
        m = sum(np.einsum("nkp,k,nkq->pq", s, w, s) for s in sens)
        g = sum(np.einsum("nkp,k,nk->p", s, w, e) for s, e in zip(sens, res))
        return m, g

    def _weights(self, res: list[np.ndarray]) -> np.ndarray:
        return 1.0 / self._covariance(res)

    def fit(self) -> TimeDomainResults:
        """Estimate; trial steps that make the model diverge are halved, not reported."""
        with np.errstate(over="ignore", invalid="ignore"):
            return self._fit()

    def _fit(self) -> TimeDomainResults:
        theta = self._start()
        self._prepare(theta)
        cost, r = self._objective(theta)
        if not np.isfinite(cost):
            raise ValueError("the model cannot be integrated from the starting values")
        history, costs, converged, it, last_step = [float(np.prod(r))], [cost], False, 0, None
        reason = f"iteration limit ({self.max_iter}) reached"
        for it in range(1, self.max_iter + 1):
            self._prepare(theta)
            res, sens = self._sensitivities(theta)
            w = self._weights(res)
            m, g = self._information(res, sens, w)
            step = None
            # the Gauss-Newton step, then, if no halving of it lowers the cost (a poor quadratic model: a
            # constraint nearly active, inaccurate sensitivities), steps damped toward the gradient
            for damping, halvings in ((0.0, 11), (1e-2, 6), (1.0, 6), (1e2, 6)):
                md = m + damping * np.diag(np.diag(m))
                step = self._line_search(theta, self._constrain(theta, solve_scaled(md, g), md, g), cost, halvings)
                if step is not None:
                    break
            if step is None:
                # no step lowers the cost: at the (constrained) minimum to numerical precision when the
                # estimator's other unknowns are settled too (_stalled), when the last accepted step had
                # nearly stopped changing the cost, or moved no estimate by more than a small part of its
                # Cramér-Rao bound
                settled = self._stalled(theta, it, cost, r)
                if not isinstance(settled, bool):
                    theta, c, r = settled
                    cost, last_step = c, None
                    costs.append(cost)
                    history.append(float(np.prod(r)))
                    continue
                last = abs(np.expm1(costs[-1] - costs[-2])) if len(costs) > 1 else float("nan")
                moved = float(np.max(np.abs(last_step) / bounds(m))) if last_step is not None else float("nan")
                converged = settled or last < 10 * self.tol or moved < STILL_SE
                reason = (
                    ""
                    if converged
                    else (
                        f"no step lowered the cost at iteration {it} (Gauss-Newton and damped steps, each halved); the last "
                        f"accepted step changed it by {last:.2g} (tolerance {self.tol:g}) and moved an estimate by "
                        f"{moved:.2g} of its Cramér-Rao bound"
                    )
                )
                break
            trial, c, r = step
            last_step = trial - theta
            theta, c, r = self._after_step(trial, it, c, r)
            change = abs(np.expm1(c - cost))
            cost = c
            costs.append(cost)
            history.append(float(np.prod(r)))
            if change < self.tol or np.max(np.abs(last_step) / bounds(m)) < STILL_SE:
                converged, reason = True, ""
                break
        else:
            reason += f", the cost still changing by {abs(np.expm1(costs[-1] - costs[-2])):.2g} a step"
        out = self._results(theta, history, converged, it)
        out.reason = reason
        return out

    def _results(self, theta, history, converged, iterations) -> TimeDomainResults:
        self._prepare(theta)
        res, sens = self._sensitivities(theta)
        r = self._covariance(res)
        w = 1.0 / r
        m, _ = self._information(res, sens, w)
        cov = np.linalg.inv(m)
        middle = np.zeros_like(m)
        for e, s in zip(res, sens):
            for k in range(e.shape[1]):
                middle += w[k] ** 2 * lagged_gram(s[:, k, :], e[:, k], len(e) - 1)
        cov_c = cov @ middle @ cov
        preds = [z - e for z, e in zip((rec.z for rec in self.records), res)]
        idx = pd.Index(self.names)
        return TimeDomainResults(
            self.method,
            pd.Series(theta, index=idx),
            pd.Series(np.sqrt(np.diag(cov)), index=idx),
            pd.Series(np.sqrt(np.diag(cov_c)), index=idx),
            pd.Series(r, index=self.model.outputs),
            float(np.prod(r)),
            history,
            converged,
            iterations,
            preds,
            res,
            cov,
            cov_c,
        )
