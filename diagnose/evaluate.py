"""The model aircraft's own aerodynamics at measured states, computed by JSBSim.

The diagnosis must not re-implement the model's aerodynamics: JSBSim computes
them, from an evaluation copy of the model aircraft. Any JSBSim aircraft works;
nothing here assumes ours. The copy differs from the model in three ways:

- it has no flight-control system, so the measured surface, flap and gear
  positions are set directly; every other FCS output that moves with them
  (a normalised elevator, a flap angle computed from a flap norm, a gear angle)
  is set from the model's own control schedules (:mod:`infra.model`);
- ``aero/alphadot-*``, ``aero/betadot-*`` and ``aero/cl-squared`` are read
  from settable ``eval/`` properties. When JSBSim flies, it computes them
  from the previous frame (α̇ from the previous frame's accelerations, CL²
  from the previous frame's lift). Here α̇ and β̇ come from the measured α
  and β, and CL² from the measured lift coefficient, both taken one frame
  (:attr:`ModelEvaluator.frame_s`) before the sample, as JSBSim has them;
- network ``<input>``/``<output>`` elements are removed;
- if its aerodynamics read nothing an engine or a landing-gear contact computes
  (:data:`WITHOUT_ENGINES`), its engines and contacts are removed: they cost a
  sixth of each ``run_ic()`` and move none of the aero forces (the tanks stay, and
  with them the CG).

Each sample is set as an initial condition and ``run_ic()`` evaluates every
aero function there, at the raw (unfiltered) measured state. The pitching
moment is returned about the model's aerodynamic reference point (AERORP),
where JSBSim applies the aero forces, with the full x and z offset from the
model's CG.
"""

from __future__ import annotations

import array
import hashlib
import shutil
import threading
import weakref
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from multiprocessing.util import Finalize
from pathlib import Path

import numpy as np
import pandas as pd

from identify.kinematics import angle_rates
from infra.model import (
    FCS_SECTIONS,
    PROPERTY_TAGS,
    captured_stdout,
    catalog,
    component_outputs,
    control_schedules,
    copy_model,
    declared,
    fcs_sections,
    load_fdm,
    longitudinal_inputs,
    mentioned,
    reads,
)
from infra.pool import owned_tmpdir

D2R = np.pi / 180.0
#: JSBSim properties computed from the previous frame, and the settable stand-ins of the copy.
REDIRECT = {
    "aero/alphadot-rad_sec": "eval/alphadot-rad_sec",
    "aero/alphadot-deg_sec": "eval/alphadot-deg_sec",
    "aero/betadot-rad_sec": "eval/betadot-rad_sec",
    "aero/betadot-deg_sec": "eval/betadot-deg_sec",
    "aero/cl-squared": "eval/cl-squared",
}
#: Properties JSBSim derives from the state set as an initial condition.
STATE_DERIVED = (
    "aero/alpha",
    "aero/beta",
    "aero/mag-beta",
    "aero/qbar",
    "aero/ci2vel",
    "aero/bi2vel",
    "aero/h_b-",
    "velocities/",
    "atmosphere/",
    "position/h-",
    "attitude/",
    "metrics/",
)
IC_CHANNELS = (
    ("ic/h-sl-ft", "alt_ft", 1.0),
    ("ic/vt-kts", "tas_kt", 1.0),
    ("ic/alpha-deg", "alpha_deg", 1.0),
    ("ic/beta-deg", "beta_deg", 1.0),
    ("ic/theta-deg", "theta_deg", 1.0),
    ("ic/phi-deg", "phi_deg", 1.0),
    ("ic/p-rad_sec", "p_dps", D2R),
    ("ic/q-rad_sec", "q_dps", D2R),
    ("ic/r-rad_sec", "r_dps", D2R),
)


#: What an evaluation copy's aerodynamics may read for its engines and landing-gear contacts to be
#: left out: the state set as an initial condition, the atmosphere, the geometry, the control
#: positions and what the evaluation sets or holds. Anything else (a propeller's induced velocity,
#: the weight on a wheel, a force, a tank's contents) keeps them.
WITHOUT_ENGINES = (
    "velocities/",
    "atmosphere/",
    "metrics/",
    "attitude/",
    "position/",
    "fcs/",
    "eval/",
    "aero/alpha-",
    "aero/beta-",
    "aero/mag-beta-",
    "aero/ci2vel",
    "aero/bi2vel",
    "aero/h_b-",
    "aero/qbar-psf",
    "aero/qbarUW-psf",
    "aero/qbarUV-psf",
    "aero/qbar-area",
    "aero/cl-squared",
    "aero/Re",
    "gear/gear-pos-norm",
)


def moment_transfer(
    cm: np.ndarray, cx: np.ndarray, cz: np.ndarray, dx_in: float, dz_in: float, cbar_ft: float
) -> np.ndarray:
    """Pitching-moment coefficient moved from point A to point B.

    Parameters
    ----------
    cm : ndarray
        Cm about A [-].
    cx, cz : ndarray
        Body-axis force coefficients of the force acting at B [-] (x forward, z down).
    dx_in, dz_in : float
        B minus A in JSBSim structural axes (x aft, z up) [in].
    cbar_ft : float
        Reference chord [ft].

    Returns
    -------
    ndarray
        Cm about B [-]: ``Cm_A = Cm_B + r x F`` with r from A to B in body axes.
    """
    return cm + (dz_in * cx - dx_in * cz) / (12.0 * cbar_ft)


def _redirect(aero: ET.Element) -> set[str]:
    """Point every read of :data:`REDIRECT` properties at the stand-ins; return those used."""
    used = set()
    for el in aero.iter():
        if el.tag in PROPERTY_TAGS and el.text:
            raw = el.text.strip()
            sign, name = ("-", raw[1:]) if raw.startswith("-") else ("", raw)
            if name in REDIRECT:
                el.text = sign + REDIRECT[name]
                used.add(REDIRECT[name])
    return used


def _own_properties(root: Path, name: str, removed: set[str]) -> set[str]:
    """JSBSim's own properties of the model at ``root``, loaded as a probe.

    The properties in ``removed`` (what the sections left out of the probe defined) are
    made before the probe goes: where another part of the model reads one (a gas cell the
    aerodynamics' surface area, an engine a removed system's starter voltage), JSBSim's
    destructor reads it and, not finding it, aborts the process.
    """
    fdm = load_fdm(root, name)
    own = set(catalog(fdm))
    pm = fdm.get_property_manager()
    for p in removed - own:
        pm.get_node(p, True)
    return own


def evaluation_copy(model_dir: Path, root: Path) -> tuple[Path, set[str], set[str], set[str]]:
    """Write ``root/aircraft/<name>/``: the model without FCS and network I/O (and without
    engines and gear contacts if its aerodynamics need none, :data:`WITHOUT_ENGINES`).

    The properties the removed FCS wrote are declared settable, and the
    aerodynamics read :data:`REDIRECT`'s stand-ins.

    Returns
    -------
    folder : Path
    outputs : set of str
        Properties the removed FCS wrote.
    builtin : set of str
        JSBSim's own properties of the model (not declared again).
    redirected : set of str
        The ``eval/`` stand-ins the aerodynamics read.
    """
    model_dir = Path(model_dir)
    name = model_dir.name
    dest, tree = copy_model(model_dir, root)
    top = tree.getroot()
    outputs: set[str] = set()
    removed: set[str] = set()  # what the sections the probe lacks read, declare or define
    values: dict[str, float] = {}  # what the removed sections declare, at its declared value
    for sec in fcs_sections(top, model_dir):
        outputs |= component_outputs(sec)
        removed |= mentioned(sec)
        values.update(declared(sec))
    for tag in FCS_SECTIONS:
        for el in top.findall(tag):
            top.remove(el)
    aero = top.find("aerodynamics")
    redirected = _redirect(aero)
    read = reads(aero)
    removed |= outputs | mentioned(aero)
    kept = list(aero)
    for el in kept:  # a probe without aerodynamics lists JSBSim's own properties
        aero.remove(el)
    whole = {sec: list(sec) for name_ in ("propulsion", "ground_reactions") for sec in top.findall(name_)}
    strip = all(p in outputs | redirected or p.startswith(WITHOUT_ENGINES) for p in read)
    for sec in whole if strip else ():
        for el in [el for el in sec if el.tag in ("engine", "contact")]:
            sec.remove(el)
    tree.write(dest / f"{name}.xml", xml_declaration=True, encoding="unicode")
    builtin = _own_properties(root, name, removed)
    if strip and not read <= builtin | outputs | redirected:  # an engine's own FCS property (a throttle)
        for sec, children in whole.items():
            sec[:] = children
        tree.write(dest / f"{name}.xml", xml_declaration=True, encoding="unicode")
        builtin = _own_properties(root, name, removed)
    aero.extend(kept)
    fcs = ET.SubElement(top, "flight_control", name="evaluation: positions set directly")
    for prop in sorted((outputs | redirected | set(values)) - builtin):
        ET.SubElement(fcs, "property", value=repr(values.get(prop, 0.0))).text = prop
    tree.write(dest / f"{name}.xml", xml_declaration=True, encoding="unicode")
    return dest, outputs, builtin, redirected


@dataclass(frozen=True)
class UnsetInput:
    """A property the model's lift, drag or pitching moment read that no log channel sets."""

    name: str
    value: float

    def __str__(self) -> str:
        return f"{self.name} (held at {self.value:g})"


@dataclass(frozen=True)
class Reference:
    """A model's reference geometry: what eq. (1)'s coefficients need to be put in its terms.

    Attributes
    ----------
    S : float
        Wing area [ft^2].
    cbar : float
        Reference chord [ft].
    aerorp_in, cg_in : tuple
        AERORP and CG, structural x, y, z [in].
    """

    S: float
    cbar: float
    aerorp_in: tuple
    cg_in: tuple


class ModelEvaluator:
    """Evaluate a model aircraft's CL, CD and Cm (about its AERORP) at measured states.

    Parameters
    ----------
    model_dir : Path
        A JSBSim aircraft folder (``<name>.xml`` inside).

    Attributes
    ----------
    schedules : dict
        The model's control schedules (:func:`infra.model.control_schedules`).
    unset : list of UnsetInput
        Inputs of the model's lift, drag and pitching moment that the logs do
        not set; they keep the value shown (normally 0, as in level flight).
    frame_s : float
        JSBSim's frame [s]: α̇, β̇ and CL² are taken this long before each sample.
    jobs : int
        Worker processes :func:`diagnose.residuals.residual_data` spreads the logs over
        (each evaluates the same model with JSBSim of its own).
    aerorp_in, cg_in : tuple
        The model's AERORP and CG, structural x, y, z [in].
    """

    def __init__(self, model_dir: Path, jobs: int = 1) -> None:
        self.model_dir = Path(model_dir)
        self.jobs = jobs
        name = self.model_dir.name
        self._tmp = owned_tmpdir("eval")
        # removed by close(), or when the evaluator is collected or the process ends, whichever is first
        self._remove = weakref.finalize(self, shutil.rmtree, self._tmp, ignore_errors=True)
        try:
            copy_model(self.model_dir, self._tmp / "full")
            model_fdm = load_fdm(self._tmp / "full", name)
            folder, outputs, builtin, redirected = evaluation_copy(self.model_dir, self._tmp / "eval")
            self.schedules = control_schedules(
                model_fdm, outputs | {p for p in builtin if p.startswith(("fcs/", "gear/gear-"))}
            )
            self.fdm = load_fdm(self._tmp / "eval", name)
        except BaseException:
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise
        fdm = self.fdm
        self.names = catalog(fdm)
        self.redirected = redirected
        self.frame_s = float(model_fdm.get_delta_t())
        self.S = fdm["metrics/Sw-sqft"]
        self.cbar = fdm["metrics/cbarw-ft"]
        self._start()
        self.aerorp_in = tuple(fdm[f"metrics/aero-rp-{a}-in"] for a in "xyz")
        self.cg_in = tuple(fdm[f"inertia/cg-{a}-in"] for a in "xyz")
        inputs = longitudinal_inputs(ET.parse(folder / f"{name}.xml").getroot())
        settable = {s.position for s in self.schedules.values()} | set(redirected)
        for s in self.schedules.values():
            settable |= set(s.outputs)
        self.unset = [
            UnsetInput(p, float(fdm[p]) if p in self.names else 0.0)
            for p in sorted(inputs)
            if p not in settable
            and not p.startswith(STATE_DERIVED)
            and not p.startswith("eval/")
            and not (p.startswith("fcs/mag-") and "fcs/" + p[8:] in settable)
        ]

    def _start(self) -> None:
        self.fdm["ic/vt-kts"] = 200.0
        with captured_stdout():
            self.fdm.run_ic()

    def restart(self) -> "ModelEvaluator":
        """This evaluator with its JSBSim model loaded again (3 ms on our 737): a row's answer
        depends in its last digits (1e-13) on the rows evaluated before it (JSBSim's
        initial-condition setters start from the previous state), so work that restarts the
        model at fixed places gives the same numbers whichever process runs it."""
        with captured_stdout():
            self.fdm = load_fdm(self._tmp / "eval", self.model_dir.name)
        self._start()
        return self

    @property
    def reference(self) -> Reference:
        """The model's reference geometry, without JSBSim (it pickles to worker processes)."""
        return Reference(self.S, self.cbar, self.aerorp_in, self.cg_in)

    def _controls(self, data: pd.DataFrame) -> dict[str, np.ndarray]:
        """Every FCS output to set, from the measured control channels."""
        n = len(data)
        out: dict[str, np.ndarray] = {}
        for ch, s in self.schedules.items():
            measured = ch in data.columns
            if not s.moves:
                if measured and float(np.max(np.abs(data[ch]))) > 1e-6:
                    raise ValueError(
                        f"{self.model_dir.name}: the logs have {ch} up to "
                        f"{float(np.max(np.abs(data[ch]))):g} but the model's flight controls "
                        f"never move {s.position}"
                    )
                values = np.zeros(n)
            else:
                values = data[ch].to_numpy(dtype=float) if measured else np.zeros(n)
            for prop, v in s.settings(values).items():
                if self.names.get(prop):
                    out[prop] = v
            if self.names.get(s.position):
                out[s.position] = values / s.scale
        return out

    def _derived(self, data: pd.DataFrame, cl: np.ndarray | None) -> dict[str, np.ndarray]:
        """α̇, β̇ and CL² as JSBSim has them: from the previous frame."""
        out = {}
        if self.redirected & {
            "eval/alphadot-rad_sec",
            "eval/alphadot-deg_sec",
            "eval/betadot-rad_sec",
            "eval/betadot-deg_sec",
        }:
            adot, bdot = angle_rates(data, lag_s=self.frame_s)
            out.update(
                {
                    "eval/alphadot-rad_sec": adot,
                    "eval/alphadot-deg_sec": adot / D2R,
                    "eval/betadot-rad_sec": bdot,
                    "eval/betadot-deg_sec": bdot / D2R,
                }
            )
        if "eval/cl-squared" in self.redirected:
            if cl is None:
                raise ValueError(f"{self.model_dir.name}: the model reads aero/cl-squared: give the measured CL")
            # JSBSim: the previous frame's lift over this frame's dynamic pressure, squared
            t = data["t_s"].to_numpy(dtype=float)
            qbar = data["qbar_psf"].to_numpy(dtype=float)
            out["eval/cl-squared"] = (np.interp(t - self.frame_s, t, cl * qbar) / qbar) ** 2
        return {k: v for k, v in out.items() if k in self.redirected}

    def inputs(self, data: pd.DataFrame, cl: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Every property the evaluation sets, per row of a log: the state as an
        initial condition, the control positions and their schedules, α̇, β̇, CL².

        Parameters
        ----------
        data : DataFrame
            A log in the schema, in time order.
        cl : ndarray, optional
            Measured lift coefficient [-] at each row; needed when the model
            reads ``aero/cl-squared``.
        """
        zeros = np.zeros(len(data))
        out = {p: data[c].to_numpy(dtype=float) * k if c in data else zeros for p, c, k in IC_CHANNELS}
        out.update(self._controls(data))
        out.update(self._derived(data, cl))
        return out

    def evaluate(self, inputs: dict[str, np.ndarray], rows: np.ndarray | None = None) -> pd.DataFrame:
        """CL, CD and Cm about the model's AERORP, JSBSim evaluating each row of ``inputs``.

        Parameters
        ----------
        inputs : dict
            Property -> values (:meth:`inputs`).
        rows : ndarray of int, optional
            Evaluate these rows only (default all).
        """
        return pd.DataFrame(self.evaluate_array(inputs, rows), columns=["CL", "CD", "Cm"])

    def evaluate_array(self, inputs: dict[str, np.ndarray], rows: np.ndarray | None = None) -> np.ndarray:
        """:meth:`evaluate` as an array (rows, 3): CL, CD, Cm [-] (no frame to build for a few rows)."""
        n = len(next(iter(inputs.values())))
        rows = np.arange(n) if rows is None else np.asarray(rows)
        values = {p: np.asarray(v, dtype=float)[rows] for p, v in inputs.items()}
        # a control position the same in every row is set once; an initial-condition setter never
        # is (each recomputes the state from the others)
        fixed = [p for p, v in values.items() if not p.startswith("ic/") and len(v) and bool(np.all(v == v[0]))]
        raw = self._aero_forces(values, fixed, len(rows))
        if raw is None:  # run_ic() moved a position set once: every input in every row
            raw = self._aero_forces(values, [], len(rows))
        qs = raw[:, 0] * self.S
        cm_cg = raw[:, 5] / (qs * self.cbar)
        dx = self.aerorp_in[0] - self.cg_in[0]
        dz = self.aerorp_in[2] - self.cg_in[2]
        cm = moment_transfer(cm_cg, raw[:, 3] / qs, raw[:, 4] / qs, dx, dz, self.cbar)
        return np.column_stack([raw[:, 1] / qs, raw[:, 2] / qs, cm])

    def _aero_forces(self, values: dict[str, np.ndarray], fixed: list[str], n: int) -> np.ndarray | None:
        """qbar [psf], the aero lift and drag, body x and z forces [lbf] and pitching moment about
        the CG [lbf ft] at each of the ``n`` rows of ``values``, JSBSim's ``run_ic()`` at each; the
        properties in ``fixed`` (the same in every row) are set once first. None if ``run_ic()``
        moved one of them."""
        fdm = self.fdm
        pm = fdm.get_property_manager()
        for p in fixed:
            pm.get_node(p, False).set_double_value(float(values[p][0]))
        held = [(pm.get_node(p, False), pm.get_node(p, False).get_double_value()) for p in fixed]
        # the rows' values as Python floats: indexing a list costs a third of indexing an array
        sets = [(pm.get_node(p, False).set_double_value, v.tolist()) for p, v in values.items() if p not in fixed]
        read = [
            pm.get_node(p, False)
            for p in (
                "aero/qbar-psf",
                "forces/fwz-aero-lbs",
                "forces/fwx-aero-lbs",
                "forces/fbx-aero-lbs",
                "forces/fbz-aero-lbs",
                "moments/m-aero-lbsft",
            )
        ]
        get = type(read[0]).get_double_value
        out = array.array("d")
        with captured_stdout():
            for j in range(n):
                for put, v in sets:
                    put(v[j])
                fdm.run_ic()
                out.extend(map(get, read))
        if any(node.get_double_value() != before for node, before in held):
            return None
        return np.frombuffer(out, dtype=float).reshape(-1, len(read))

    def predict(self, data: pd.DataFrame, cl: np.ndarray | None = None) -> pd.DataFrame:
        """CL, CD and Cm about the model's AERORP at each row of ``data`` (see :meth:`inputs`).

        Returns
        -------
        DataFrame
            ``CL``, ``CD`` and ``Cm`` [-], ``Cm`` about the model's AERORP, indexed like ``data``.
        """
        return pd.DataFrame(self.evaluate_array(self.inputs(data, cl)), columns=["CL", "CD", "Cm"], index=data.index)

    def close(self) -> None:
        self._remove()


_EVALUATORS = threading.local()  # per thread: a Dask worker may run several tasks at once


def evaluator_for(model_dir: Path) -> ModelEvaluator:
    """This process's (thread's) evaluator of a model folder, made once per folder content (in
    worker processes). Its temporary copy goes when the process ends (a worker too runs
    multiprocessing's finalizers before it exits), or when another model's evaluator replaces it.
    """
    model_dir = Path(model_dir)
    digest = hashlib.sha1()
    for f in sorted(p for p in model_dir.rglob("*") if p.is_file()):
        digest.update(str(f.relative_to(model_dir)).encode() + b"\0" + f.read_bytes())
    key = (str(model_dir.resolve()), digest.hexdigest())
    held = getattr(_EVALUATORS, "held", None)
    if held is None or held[0] != key:
        if held is not None:
            held[1].close()  # one model at a time: a worker serves one diagnosis
        ev = ModelEvaluator(model_dir)
        Finalize(ev, shutil.rmtree, args=(ev._tmp,), kwargs={"ignore_errors": True}, exitpriority=0)
        _EVALUATORS.held = (key, ev)
    return _EVALUATORS.held[1]


#: The logs a task of :func:`by_log_chunks` evaluates, at most.
CHUNK_LOGS = 8


def by_log_chunks(func, logs: list, evaluator: "ModelEvaluator", jobs: int, *args, wait: bool = True):
    """``func(chunk, evaluator, *args)`` (a list back) over ``logs`` cut into chunks of at most
    :data:`CHUNK_LOGS`, the results joined in order. With ``jobs`` > 1 each chunk is a task
    for the workers, which pass their own evaluator of the same model (:func:`evaluator_for`), on the
    Dask cluster within :func:`infra.pool.on_cluster` (the model folder shipped with the tasks);
    else they run here, one after another. Each chunk starts from a freshly loaded model
    (:meth:`ModelEvaluator.restart`): the chunks do not depend on the number of workers, so
    neither do the numbers, to the bit, whichever worker runs which chunk.

    With ``wait=False`` a callable that returns the results comes back: the workers start at once
    and this process goes on meanwhile (with one job the work is done on the call).
    """
    chunks = [list(logs[i : i + CHUNK_LOGS]) for i in range(0, len(logs), CHUNK_LOGS)]
    if jobs <= 1 or len(chunks) <= 1:

        def here() -> list:
            return [x for c in chunks for x in func(c, evaluator.restart(), *args)]

        return here() if wait else here
    from infra.pool import cluster, results, ship, submit

    model = ship(evaluator.model_dir) if cluster() is not None else evaluator.model_dir  # other machines' files
    futures = submit(_in_worker, [(func, c, model, args) for c in chunks], jobs)

    def joined() -> list:
        return [x for part in results(futures) for x in part]

    return joined() if wait else joined


def _in_worker(func, chunk: list, model, args: tuple) -> list:
    from infra.pool import Shipment, landed

    model_dir = landed(model) / model.name if isinstance(model, Shipment) else model
    return func(chunk, evaluator_for(model_dir).restart(), *args)


def in_chunks(func, items: list, jobs: int, *args, wait: bool = True):
    """``func(chunk, *args)`` (a list back) over ``items`` cut into ``jobs`` contiguous chunks, each
    in a worker process (in this one if ``jobs`` is 1), the results joined in order.

    With ``wait=False`` a callable that returns them is returned instead: the workers start
    at once and this process goes on meanwhile (with one job the work is done on the call).
    """
    n = min(jobs, len(items))
    if n <= 1:
        return func(list(items), *args) if wait else lambda: func(list(items), *args)
    from infra.pool import results, submit

    futures = submit(func, [([items[i] for i in c], *args) for c in np.array_split(np.arange(len(items)), n)], jobs)

    def joined() -> list:
        return [x for part in results(futures) for x in part]

    return joined() if wait else joined
