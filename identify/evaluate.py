"""The model aircraft's own aerodynamics at measured states, computed by JSBSim.

The diagnosis must not re-implement the model's aerodynamics. JSBSim computes
them, from an evaluation copy of the model aircraft: the same XML without its
flight-control system, so the measured surface, flap and gear positions can be
set directly (an FCS would move them through its actuators). Each state is set
as an initial condition; ``run_ic()`` then evaluates every aero function there.
This module uses JSBSim as a calculator of the model; it does not fly anything.
"""
from __future__ import annotations

import os
import shutil
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pandas as pd

os.environ.setdefault("JSBSIM_DEBUG", "0")

D2R = np.pi / 180.0
FLAP_DETENTS_DEG = (0, 1, 2, 5, 10, 15, 25, 30, 40)
#: Measured channel -> JSBSim properties it sets (with scale).
SETS = {
    "elevator_deg": (("fcs/elevator-pos-rad", D2R), ("fcs/elevator-pos-deg", 1.0)),
    "stabilizer_deg": (("fcs/stabilizer-pos-rad", D2R), ("fcs/stabilizer-pos-deg", 1.0)),
    "flap_deg": (("fcs/flap-pos-deg", 1.0),),
    "gear_norm": (("gear/gear-pos-norm", 1.0),),
}
FCS_SECTIONS = ("flight_control", "autopilot", "system")


def _component_outputs(section: ET.Element) -> set[str]:
    names = set()
    for el in section.iter():
        if el.tag == "output" and el.text:
            names.add(el.text.strip())
        elif el.get("name") and el.tag not in ("channel", "flight_control", "autopilot", "system", "property"):
            n = el.get("name").strip()
            names.add(n if "/" in n else "fcs/" + n.lower().replace(" ", "-"))
    return names


def evaluation_copy(model_dir: Path, root: Path) -> Path:
    """Write ``root/aircraft/<name>/`` without FCS, its outputs declared as properties."""
    model_dir = Path(model_dir)
    name = model_dir.name
    dest = root / "aircraft" / name
    shutil.copytree(model_dir, dest, ignore=shutil.ignore_patterns("effects", "__pycache__"))
    tree = ET.parse(dest / f"{name}.xml")
    top = tree.getroot()
    outputs: set[str] = set()
    for tag in FCS_SECTIONS:
        for sec in top.findall(tag):
            outputs |= _component_outputs(sec)
            top.remove(sec)
    for tag in ("input", "output"):
        for el in top.findall(tag):
            top.remove(el)
    builtin = {"fcs/elevator-pos-rad", "fcs/elevator-pos-deg", "fcs/elevator-pos-norm", "fcs/flap-pos-deg",
               "fcs/flap-pos-norm", "fcs/flap-pos-rad", "gear/gear-pos-norm", "fcs/left-aileron-pos-rad",
               "fcs/right-aileron-pos-rad", "fcs/rudder-pos-rad", "fcs/speedbrake-pos-norm",
               "fcs/spoiler-pos-norm", "fcs/throttle-pos-norm"}
    fcs = ET.SubElement(top, "flight_control", name="evaluation: surfaces set directly")
    for prop in sorted(outputs - builtin):
        ET.SubElement(fcs, "property", value="0").text = prop
    tree.write(dest / f"{name}.xml", xml_declaration=True, encoding="unicode")
    return dest


class ModelEvaluator:
    """Evaluate a model aircraft's CL, CD and Cm (about the CG) at measured states.

    Parameters
    ----------
    model_dir : Path
        A JSBSim aircraft folder (``<name>.xml`` inside).
    """

    def __init__(self, model_dir: Path) -> None:
        import jsbsim

        self.model_dir = Path(model_dir)
        self._tmp = Path(tempfile.mkdtemp(prefix="gearid-eval-"))
        folder = evaluation_copy(self.model_dir, self._tmp)
        fdm = jsbsim.FGFDMExec(str(self._tmp))
        fdm.set_debug_level(0)
        engines = folder / "Engines"
        fdm.set_engine_path(str(engines) if engines.is_dir() else os.path.join(jsbsim.get_default_root_dir(), "engine"))
        fdm.set_systems_path(os.path.join(jsbsim.get_default_root_dir(), "systems"))
        if not fdm.load_model(folder.name):
            raise ValueError(f"{self.model_dir}: JSBSim could not load the model for evaluation")
        self.fdm = fdm
        names = {e.split(" ")[0].replace("[0]", "") for e in fdm.get_property_catalog()}
        self.sets = {ch: tuple((p, k) for p, k in props if p in names) for ch, props in SETS.items()}
        self.S = fdm["metrics/Sw-sqft"]
        self.cbar = fdm["metrics/cbarw-ft"]

    def predict(self, states: pd.DataFrame) -> pd.DataFrame:
        """CL, CD, Cm of the model at each row of ``states`` (log-schema columns).

        Uses alt_ft, tas_kt, alpha_deg, beta_deg, theta_deg, phi_deg, p/q/r_dps
        and the surface, flap and gear positions.
        """
        fdm = self.fdm
        out = np.empty((len(states), 3))
        cols = {c: states[c].to_numpy() for c in states.columns}
        beta = cols.get("beta_deg", np.zeros(len(states)))
        for i in range(len(states)):
            fdm["ic/h-sl-ft"] = cols["alt_ft"][i]
            fdm["ic/vt-kts"] = cols["tas_kt"][i]
            fdm["ic/alpha-deg"] = cols["alpha_deg"][i]
            fdm["ic/beta-deg"] = beta[i]
            fdm["ic/theta-deg"] = cols["theta_deg"][i]
            fdm["ic/phi-deg"] = cols["phi_deg"][i]
            fdm["ic/p-rad_sec"] = cols["p_dps"][i] * D2R
            fdm["ic/q-rad_sec"] = cols["q_dps"][i] * D2R
            fdm["ic/r-rad_sec"] = cols["r_dps"][i] * D2R
            for ch, props in self.sets.items():
                for prop, k in props:
                    fdm[prop] = cols[ch][i] * k
            fdm["fcs/flap-pos-norm"] = np.interp(cols["flap_deg"][i], FLAP_DETENTS_DEG,
                                                 np.linspace(0, 1, len(FLAP_DETENTS_DEG)))
            fdm.run_ic()
            qs = fdm["aero/qbar-psf"] * self.S
            out[i] = (fdm["forces/fwz-aero-lbs"] / qs, fdm["forces/fwx-aero-lbs"] / qs,
                      fdm["moments/m-aero-lbsft"] / (qs * self.cbar))
        return pd.DataFrame(out, columns=["CL", "CD", "Cm"], index=states.index)

    def close(self) -> None:
        shutil.rmtree(self._tmp, ignore_errors=True)
