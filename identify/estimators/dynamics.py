"""State-space models for the time-domain estimators, and their integration.

A model is ``dx/dt = f(x, u, p)``, ``y = g(x, u, p)``. Both functions are evaluated on a
batch: ``x`` of shape (B, nx), ``u`` of shape (nu,) (one sample, shared), ``p`` of shape
(B, np); they return (B, nx) and (B, ny). The estimators integrate the unperturbed model
and all its parameter perturbations as one batch, so finite-difference sensitivities cost
one pass over the data, not one per parameter. A model that cannot be batched (a JSBSim
aircraft) loops over the rows itself.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class StateSpaceModel:
    """``dx/dt = f(x, u, p)``, ``y = g(x, u, p)``, batched over the first axis.

    Parameters
    ----------
    f, g : callable
        ``f(x (B, nx), u (nu,), p (B, np)) -> (B, nx)`` and the same for the outputs.
    states, inputs, outputs, params : tuple of str
        Names, units in them.
    """

    f: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
    g: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    params: tuple[str, ...]


@dataclass(frozen=True)
class Record:
    """One manoeuvre: sampled inputs and measured outputs on a uniform time base.

    Parameters
    ----------
    u : ndarray, shape (N, nu)
    z : ndarray, shape (N, ny)
        Measured outputs, in the model's output order.
    dt_s : float
        Sample interval [s].
    x0 : ndarray, shape (nx,)
        Initial state (a starting value when it is estimated).
    name : str
    """

    u: np.ndarray
    z: np.ndarray
    dt_s: float
    x0: np.ndarray
    name: str = "record"
    t_s: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "u", np.atleast_2d(np.asarray(self.u, dtype=float).T).T)
        object.__setattr__(self, "z", np.atleast_2d(np.asarray(self.z, dtype=float).T).T)
        object.__setattr__(self, "x0", np.asarray(self.x0, dtype=float))
        if len(self.u) != len(self.z):
            raise ValueError(f"{self.name}: {len(self.u)} input samples but {len(self.z)} output samples")

    @property
    def n(self) -> int:
        return len(self.z)


def rk4_step(f: Callable, x: np.ndarray, u1: np.ndarray, u2: np.ndarray, p: np.ndarray, dt: float) -> np.ndarray:
    """One fourth-order Runge-Kutta step, the input linear between its samples (mid-step: the mean)."""
    um = 0.5 * (u1 + u2)
    k1 = f(x, u1, p)
    k2 = f(x + 0.5 * dt * k1, um, p)
    k3 = f(x + 0.5 * dt * k2, um, p)
    k4 = f(x + dt * k3, u2, p)
    return x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def simulate(
    model: StateSpaceModel, p: np.ndarray, x0: np.ndarray, rec: Record, gain: np.ndarray | None = None
) -> np.ndarray:
    """Outputs of the model over one record, for a batch of parameter vectors.

    Parameters
    ----------
    p : ndarray, shape (B, np)
    x0 : ndarray, shape (B, nx)
    gain : ndarray, shape (B, nx, ny), optional
        A steady-state Kalman gain: the states are corrected by the innovations at every
        sample before they are propagated (the filter error method's predictor). None: a
        pure simulation (output error).

    Returns
    -------
    ndarray, shape (B, N, ny)
        The predicted outputs (before the correction at each sample).
    """
    x = np.array(x0, dtype=float)
    y = np.empty((len(p), rec.n, len(model.outputs)))
    for k in range(rec.n):
        y[:, k] = model.g(x, rec.u[k], p)
        if gain is not None:
            x = x + np.einsum("bij,bj->bi", gain, rec.z[k] - y[:, k])
        if k + 1 < rec.n:
            x = rk4_step(model.f, x, rec.u[k], rec.u[k + 1], p, rec.dt_s)
    return y


def linearize(
    model: StateSpaceModel, p: np.ndarray, x: np.ndarray, u: np.ndarray, step: float = 1e-4
) -> tuple[np.ndarray, np.ndarray]:
    """``A = df/dx`` and ``C = dg/dx`` by central differences, for a batch of parameter vectors.

    Parameters
    ----------
    p : ndarray, shape (B, np)
    x : ndarray, shape (nx,)
        The state to linearize about.
    u : ndarray, shape (nu,)

    Returns
    -------
    A : ndarray, shape (B, nx, nx)
    C : ndarray, shape (B, ny, nx)
    """
    nb, nx = len(p), len(x)
    xs = np.repeat(x[None, None, :], 2 * nx, axis=1).repeat(nb, axis=0)  # (B, 2nx, nx)
    for i in range(nx):
        xs[:, 2 * i, i] += step
        xs[:, 2 * i + 1, i] -= step
    pp = np.repeat(p[:, None, :], 2 * nx, axis=1).reshape(nb * 2 * nx, -1)
    flat = xs.reshape(nb * 2 * nx, nx)
    fx = model.f(flat, u, pp).reshape(nb, nx, 2, nx)
    gx = model.g(flat, u, pp).reshape(nb, nx, 2, -1)
    a = (fx[:, :, 0] - fx[:, :, 1]) / (2 * step)  # (B, i=state perturbed, nx)
    c = (gx[:, :, 0] - gx[:, :, 1]) / (2 * step)
    return np.transpose(a, (0, 2, 1)), np.transpose(c, (0, 2, 1))
