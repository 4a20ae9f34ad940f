"""What a JSBSim aircraft model is, read from the model itself.

Any aircraft folder, ours or someone else's: how to load it quietly, which
flight-control outputs move with each measured control (its own control
schedules, measured by sweeping its commands through its own FCS), and which
properties its longitudinal aerodynamics read. Nothing here assumes our 737.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import os
import re
import sys
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath, PureWindowsPath

import numpy as np

os.environ.setdefault("JSBSIM_DEBUG", "0")

R2D = 180.0 / np.pi
_LIBC = ctypes.CDLL(None)

#: Measured control channel -> (position property, log units per property unit,
#: command property, command range). The schedules sweep the command.
CONTROL_CHANNELS: dict[str, tuple[str, float, str, tuple[float, float]]] = {
    "elevator_deg": ("fcs/elevator-pos-rad", R2D, "fcs/elevator-cmd-norm", (-1.0, 1.0)),
    "stabilizer_deg": ("fcs/stabilizer-pos-deg", 1.0, "fcs/pitch-trim-cmd-norm", (-1.0, 1.0)),
    "flap_deg": ("fcs/flap-pos-deg", 1.0, "fcs/flap-cmd-norm", (0.0, 1.0)),
    "gear_norm": ("gear/gear-pos-norm", 1.0, "gear/gear-cmd-norm", (0.0, 1.0)),
}
FCS_SECTIONS = ("flight_control", "autopilot", "system")
SWEEP_POINTS = 401
#: Axes whose functions make CL, CD and Cm (wind, body and body axial/normal frames).
LONGITUDINAL_AXES = ("DRAG", "LIFT", "PITCH", "X", "Z", "AXIAL", "NORMAL")


_ENTITY = re.compile(rb"<!ENTITY", re.I)
_EXTERNAL_DTD = re.compile(rb"<!DOCTYPE[^>\[]*\b(?:SYSTEM|PUBLIC)\b", re.I)
_XINCLUDE = re.compile(rb"w3\.org/2001/XInclude|<[\w.-]+:include\b")


def folder_files(path: Path) -> list[tuple[str, Path]]:
    """Every file of a folder, sorted, as (POSIX path relative to it, path); caches left out."""
    files = sorted(p for p in Path(path).rglob("*") if p.is_file())
    return [(rel, f) for f in files if "__pycache__" not in (rel := f.relative_to(path).as_posix())]


def folder_hash(path: Path) -> str:
    """SHA-256 over the relative names and bytes of every file in a folder [hex]."""
    h = hashlib.sha256()
    for rel, f in folder_files(path):
        h.update(rel.encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()


def unsafe_xml(path: Path) -> str | None:
    """Why an input XML file could make a parser read or run something beyond it, or None.

    Aircraft and overlay XML are data: entity declarations (external or expanding),
    external DTDs and XInclude are refused, and so is a ``file`` attribute (JSBSim's
    include of systems, engines, thrusters) that is absolute or climbs out with ``..``.
    """
    data = Path(path).read_bytes()
    if _ENTITY.search(data):
        return "declares an XML entity (refused: aircraft and overlay XML are data)"
    if _EXTERNAL_DTD.search(data):
        return "names an external DTD (refused: nothing outside the aircraft folder is read)"
    if _XINCLUDE.search(data):
        return "uses XInclude (refused: nothing outside the aircraft folder is read)"
    try:
        root = ET.fromstring(data)
    except ET.ParseError:
        return None  # not well-formed: the caller's parse says where
    for el in root.iter():
        ref = el.get("file")
        if ref is None:
            continue
        posix = PurePosixPath(ref.replace("\\", "/"))
        if posix.is_absolute() or PureWindowsPath(ref).is_absolute() or ".." in posix.parts:
            return f'<{el.tag} file="{ref}">: reaches outside the aircraft folder (refused)'
    return None


def outside_links(folder: Path) -> tuple[Path, str] | None:
    """The first symbolic link in a folder (at any depth) that leads outside it or nowhere, and why."""
    top = Path(folder).resolve()
    for base, dirs, files in os.walk(folder):
        for name in sorted(dirs + files):
            link = Path(base) / name
            if not link.is_symlink():
                continue
            target = link.resolve()
            if not target.exists():
                return link, "a symbolic link to nothing (refused)"
            if top != target and top not in target.parents:
                return link, f"a symbolic link to {target}, outside the aircraft folder (refused)"
    return None


def unsafe_folder(folder: Path) -> tuple[Path, str] | None:
    """The first file of an aircraft folder that leads outside it (:func:`outside_links`) or XML file
    that :func:`unsafe_xml` refuses, and why."""
    link = outside_links(folder)
    if link:
        return link
    for path in sorted(Path(folder).rglob("*.xml")):
        why = unsafe_xml(path)
        if why:
            return path, why
    return None


def _collector(lines: list[str]):
    """A JSBSim logger that keeps each message as lines of text (none reach the console)."""
    import jsbsim

    class Collector(jsbsim.FGLogger):
        def __init__(self) -> None:
            super().__init__()
            self.parts: list[str] = []

        def set_level(self, level) -> None:
            self.parts = []

        def file_location(self, filename: str, line: int) -> None:
            pass

        def message(self, message: str) -> None:
            self.parts.append(message)

        def format(self, format) -> None:
            pass

        def flush(self) -> None:
            lines.extend(x.strip() for x in "".join(self.parts).splitlines() if x.strip())
            self.parts = []

    return Collector()


@contextlib.contextmanager
def captured_stdout(lines: list[str] | None = None):
    """Keep JSBSim's messages (its logger's and any written straight to the C stdout) out of
    the console, in ``lines`` if given."""
    import jsbsim

    lines = [] if lines is None else lines
    previous = jsbsim.get_logger()
    jsbsim.set_logger(_collector(lines))
    sys.stdout.flush()
    saved = os.dup(1)
    with tempfile.TemporaryFile() as buf:
        try:
            os.dup2(buf.fileno(), 1)
            yield
        finally:
            _LIBC.fflush(None)
            os.dup2(saved, 1)
            os.close(saved)
            jsbsim.set_logger(previous)
            buf.seek(0)
            lines.extend(x.strip() for x in buf.read().decode(errors="replace").splitlines() if x.strip())


def load_fdm(root: Path, name: str):
    """A fresh ``FGFDMExec`` with ``root/aircraft/<name>`` loaded, quietly.

    Engine and system files come from the aircraft's folder (JSBSim looks in it and in its
    ``Engines/`` and ``Systems/`` first), else from the jsbsim package's.

    Raises
    ------
    ValueError
        If JSBSim cannot load the model (the message names the folder).
    """
    import jsbsim

    folder = Path(root) / "aircraft" / name
    fdm = jsbsim.FGFDMExec(str(root))
    fdm.set_debug_level(0)
    fdm.set_engine_path(os.path.join(jsbsim.get_default_root_dir(), "engine"))
    fdm.set_systems_path(os.path.join(jsbsim.get_default_root_dir(), "systems"))
    said: list[str] = []
    with captured_stdout(said):
        ok = fdm.load_model(name)
    if not ok:
        # a half-loaded model reads, as it is destroyed, a property the rest of its files would have
        # defined (a Short S23 missing one of its system files)
        abandon(fdm)
        raise ModelLoadError(folder, next((s for s in said if "rror" in s), ""))
    return fdm


class ModelLoadError(ValueError):
    """JSBSim could not load a model; ``reason`` is what JSBSim said (or "")."""

    def __init__(self, folder: Path, reason: str) -> None:
        super().__init__(f"{folder}: JSBSim could not load the aircraft{': ' + reason if reason else ''}")
        self.folder, self.reason = folder, reason


def abandon(fdm) -> None:
    """Never destroy ``fdm`` (a reference nothing releases, not even the interpreter's exit).

    For a model JSBSim gave up on, loading or running: destroying it evaluates its functions once
    more, JSBSim throws from the destructor (a property nothing defines), and that aborts the process.
    """
    ctypes.pythonapi.Py_IncRef(ctypes.py_object(fdm))


def abandon_models(tb) -> None:
    """:func:`abandon` every ``FGFDMExec`` held by the frames of a traceback ``tb``."""
    import jsbsim

    while tb is not None:
        for value in list(tb.tb_frame.f_locals.values()):
            if isinstance(value, jsbsim.FGFDMExec):
                abandon(value)
        tb = tb.tb_next


def copy_model(model_dir: Path, root: Path) -> tuple[Path, ET.ElementTree]:
    """Copy an aircraft folder to ``root/aircraft/<name>/``, its XML without network I/O.

    Returns the copy's folder and its parsed XML (written already; edit and write it again
    to change the copy).
    """
    import shutil

    model_dir = Path(model_dir)
    dest = Path(root) / "aircraft" / model_dir.name
    shutil.copytree(model_dir, dest, ignore=shutil.ignore_patterns("effects", "__pycache__"))
    tree = ET.parse(dest / f"{model_dir.name}.xml")
    for tag in ("input", "output"):
        for el in tree.getroot().findall(tag):
            tree.getroot().remove(el)
    tree.write(dest / f"{model_dir.name}.xml", xml_declaration=True, encoding="unicode")
    return dest, tree


def catalog(fdm) -> dict[str, bool]:
    """Property name -> writable, for every property of a loaded model (``[0]`` dropped)."""
    out = {}
    for entry in fdm.get_property_catalog():
        name, _, flags = entry.partition(" ")
        out[name.replace("[0]", "")] = "W" in flags
    return out


def _system_file(ref: str, model_dir: Path) -> Path | None:
    import jsbsim

    name = ref if ref.endswith(".xml") else ref + ".xml"
    for d in (model_dir / "Systems", model_dir, Path(jsbsim.get_default_root_dir()) / "systems"):
        if (d / name).is_file():
            return d / name
    return None


def fcs_sections(top: ET.Element, model_dir: Path) -> list[ET.Element]:
    """The flight-control, autopilot and system sections, external files included."""
    out = []
    for tag in FCS_SECTIONS:
        for sec in top.findall(tag):
            out.append(sec)
            ref = sec.get("file")
            path = _system_file(ref, model_dir) if ref else None
            if path is not None:
                with contextlib.suppress(ET.ParseError):
                    out.append(ET.parse(path).getroot())
    return out


def component_outputs(section: ET.Element) -> set[str]:
    """Properties a flight-control section writes: explicit outputs and component names."""
    names = set()
    for el in section.iter():
        if el.tag == "output" and el.text:
            names.add(el.text.strip())
        elif el.get("name") and el.tag not in ("channel", "property", *FCS_SECTIONS):
            n = el.get("name").strip()
            names.add(n if "/" in n else "fcs/" + n.lower().replace(" ", "-"))
    return {n.replace("[0]", "") for n in names}


@dataclass
class Schedule:
    """How one measured control moves the model's flight-control outputs.

    Measured by sweeping the control's command through the model's own FCS
    with JSBSim's trim status on, so kinematics and actuators settle in one
    frame.

    Attributes
    ----------
    channel : str
        The log column (``flap_deg``...).
    position : str
        The property the log column measures (``fcs/flap-pos-deg``...).
    scale : float
        Log units per property unit.
    command : ndarray
        The swept command values, increasing.
    values : ndarray
        The position at each command [log units].
    outputs : dict
        Every other FCS output that moved, property -> value at each command.
    """

    channel: str
    position: str
    scale: float
    command: np.ndarray
    values: np.ndarray
    outputs: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def moves(self) -> bool:
        """Whether the command moves the position at all."""
        return float(np.ptp(self.values)) > 1e-9

    @property
    def range(self) -> tuple[float, float]:
        """Smallest and largest position the command reaches [log units]."""
        return float(self.values.min()), float(self.values.max())

    def _monotone(self) -> tuple[np.ndarray, np.ndarray]:
        """Positions increasing, with the command index each comes from (plateaus dropped)."""
        v = self.values if self.values[-1] >= self.values[0] else self.values[::-1]
        idx = np.arange(len(v)) if self.values[-1] >= self.values[0] else np.arange(len(v))[::-1]
        keep = np.concatenate([[True], np.diff(v) > 1e-12])
        return v[keep], idx[keep]

    def command_for(self, value: float) -> float:
        """The command that puts the position at ``value`` [log units]."""
        v, idx = self._monotone()
        return float(np.interp(value, v, self.command[idx]))

    def settings(self, values: np.ndarray) -> dict[str, np.ndarray]:
        """The other outputs at measured positions ``values`` [log units], interpolated."""
        v, idx = self._monotone()
        return {p: np.interp(values, v, y[idx]) for p, y in self.outputs.items()}


def control_schedules(fdm, watched: set[str]) -> dict[str, Schedule]:
    """Sweep each control command of a loaded model through its own FCS.

    Parameters
    ----------
    fdm : FGFDMExec
        A freshly loaded model (its full FCS); its state is changed.
    watched : set of str
        FCS outputs to record (component outputs and built-in positions).

    Returns
    -------
    dict
        Log column -> :class:`Schedule`, for the controls the model has.
    """
    names = catalog(fdm)
    fdm["ic/h-sl-ft"] = 5000.0
    fdm["ic/vt-kts"] = 200.0
    with captured_stdout():
        fdm.run_ic()
    fdm.suspend_integration()
    fdm.set_trim_status(True)
    pm = fdm.get_property_manager()
    present = sorted(p for p in watched if p in names)
    nodes = [pm.get_node(p, False) for p in present]
    out = {}
    try:
        for ch, (position, scale, command, (lo, hi)) in CONTROL_CHANNELS.items():
            if position not in names or command not in names:
                continue
            cmds = np.linspace(lo, hi, SWEEP_POINTS)
            table = np.empty((len(cmds), len(nodes)))
            pos = np.empty(len(cmds))
            for i, c in enumerate(cmds):
                fdm[command] = c
                fdm.run()
                fdm.run()
                pos[i] = fdm[position] * scale
                table[i] = [n.get_double_value() for n in nodes]
            fdm[command] = 0.0 if lo < 0 else lo
            fdm.run()
            moved = {
                p: table[:, j]
                for j, p in enumerate(present)
                if p not in (position, command) and float(np.ptp(table[:, j])) > 1e-12
            }
            out[ch] = Schedule(ch, position, scale, cmds, pos, moved)
    finally:
        fdm.set_trim_status(False)
        fdm.resume_integration()
    return out


#: The elements through which a JSBSim function or table reads a property (``<p>`` is ``<property>``).
PROPERTY_TAGS = ("property", "p", "independentVar")


def _refs(el: ET.Element) -> set[str]:
    names = set()
    for p in el.iter():
        if p.tag in PROPERTY_TAGS and p.text and p.text.strip():
            names.add(p.text.strip().lstrip("-").replace("[0]", ""))
    return names


def _defined(section: ET.Element) -> set[str]:
    return {fn.get("name") for fn in section.iter("function") if fn.get("name")}


def reads(section: ET.Element) -> set[str]:
    """Every property a section's functions and tables read, but those its own functions define."""
    return _refs(section) - _defined(section)


def declared(section: ET.Element) -> dict[str, float]:
    """The properties a section declares (``<property value="...">name</property>`` among its
    children) and their values."""
    out = {}
    for el in section.findall("property"):
        if el.text and el.text.strip():
            with contextlib.suppress(ValueError):
                out[el.text.strip().replace("[0]", "")] = float(el.get("value", 0.0))
    return out


def mentioned(section: ET.Element) -> set[str]:
    """Every property a section reads, declares or defines as a function."""
    return _refs(section) | _defined(section)


def longitudinal_inputs(top: ET.Element) -> set[str]:
    """Properties the lift, drag and pitching-moment functions read, through the
    functions they call (functions defined in ``<aerodynamics>`` resolved)."""
    aero = top.find("aerodynamics")
    if aero is None:
        return set()
    defined = {fn.get("name"): fn for fn in aero.iter("function") if fn.get("name")}
    todo = set()
    for axis in aero.findall("axis"):
        if axis.get("name", "").upper() in LONGITUDINAL_AXES:
            todo |= _refs(axis)
    seen: set[str] = set()
    while todo:
        p = todo.pop()
        if p in seen:
            continue
        seen.add(p)
        if p in defined:
            todo |= _refs(defined[p])
    return {p for p in seen if p not in defined}
