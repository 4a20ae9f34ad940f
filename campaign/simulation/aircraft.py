"""Aircraft folders and effect overlays, prepared for JSBSim.

JSBSim reads an aircraft from ``<root>/aircraft/<name>/<name>.xml``. We copy the
user's folder into a private root, merge the effect overlay into the ``<axis>``
elements of ``<aerodynamics>`` and remove every network ``<input>``/``<output>``,
so any folder (the stock JSBSim 737 included) flies without opening ports.
"""

from __future__ import annotations

import hashlib
import math
import shutil
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from aircraft import SHIPPED_737
from campaign.errors import UserError
from infra.model import PROPERTY_TAGS, folder_hash, reads, unsafe_folder, unsafe_xml
from infra.pool import owned_tmpdir

DEFAULT_AIRCRAFT = SHIPPED_737
DEFAULT_EFFECTS = DEFAULT_AIRCRAFT / "effects" / "reference.xml"
AXES = ("LIFT", "DRAG", "SIDE", "ROLL", "PITCH", "YAW")


def file_hash(path: Path) -> str:
    """SHA-256 of a file's bytes [hex]."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@dataclass(frozen=True)
class Effects:
    """A parsed, validated effect overlay.

    Attributes
    ----------
    path : str or None
        The overlay file, or None for the bare model.
    functions : tuple of (axis, xml text)
        Each ``<function>`` with the aero axis it adds to.
    """

    path: str | None
    functions: tuple[tuple[str, str], ...]

    @property
    def sha256(self) -> str | None:
        return file_hash(Path(self.path)) if self.path else None


def load_effects(path: str | Path | None) -> Effects:
    """Read and validate an effects file (``None``/``"none"``: no overlay).

    Raises
    ------
    UserError
        If the file is missing or malformed; the message names file and field.
    """
    if path is None or str(path).lower() == "none":
        return Effects(None, ())
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: effects file not found")
    why = unsafe_xml(p)
    if why:
        raise UserError(f"{p}: {why}")
    try:
        root = ET.parse(p).getroot()
    except ET.ParseError as exc:
        raise UserError(f"{p}: not well-formed XML ({exc})") from None
    if root.tag != "effects":
        raise UserError(f"{p}: root element: expected <effects>, found <{root.tag}>")
    functions = []
    for i, axis in enumerate(root):
        if axis.tag != "axis":
            raise UserError(f"{p}: <effects> child {i + 1}: expected <axis>, found <{axis.tag}>")
        name = axis.get("name", "")
        if name not in AXES:
            raise UserError(f'{p}: <axis name="{name}">: name must be one of {", ".join(AXES)}')
        for j, fn in enumerate(axis):
            if fn.tag != "function":
                raise UserError(f'{p}: <axis name="{name}"> child {j + 1}: expected <function>, found <{fn.tag}>')
            if not fn.get("name"):
                raise UserError(f'{p}: <axis name="{name}"> function {j + 1}: missing name attribute')
            if len([c for c in fn if c.tag != "description"]) != 1:
                raise UserError(f"{p}: function {fn.get('name')}: needs exactly one operation or table inside")
            _check_function(p, fn)
            functions.append((name, ET.tostring(fn, encoding="unicode")))
    names = [ET.fromstring(f).get("name") for _, f in functions]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise UserError(f"{p}: function name {sorted(dup)[0]!r} appears twice")
    return Effects(str(p.resolve()), tuple(functions))


def _finite(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


def _check_function(path: Path, fn: ET.Element) -> None:
    """Every number of an overlay function finite, every property it reads named: JSBSim refuses the
    whole aircraft otherwise, without naming the overlay."""
    where = f'{path}: <function name="{fn.get("name")}">'
    for el in fn.iter():
        text = (el.text or "").strip()
        if el.tag in ("value", "v"):
            if not _finite(text):
                raise UserError(f"{where}: <{el.tag}>{text[:40]}</{el.tag}>: not a finite number")
        elif el.tag == "tableData":
            bad = next((t for t in text.split() if not _finite(t)), None)
            if bad is not None or not text:
                raise UserError(f"{where}: <tableData>: {bad[:40] if bad else 'empty'!r} is not a finite number")
        elif el.tag in PROPERTY_TAGS and (not text or any(c.isspace() for c in text)):
            raise UserError(f"{where}: <{el.tag}>{text[:40]}</{el.tag}>: not a property name")


def overlay_reads(effects: Effects) -> list[tuple[str, str]]:
    """(function name, property) for each property an overlay's functions read but do not define."""
    fns = [ET.fromstring(text) for _, text in effects.functions]
    defined = {fn.get("name") for fn in fns}
    return [(fn.get("name"), prop) for fn in fns for prop in sorted(reads(fn)) if prop not in defined]


@dataclass(frozen=True)
class AircraftSource:
    """A JSBSim aircraft folder plus an effect overlay, as the user gave them."""

    folder: str
    effects: Effects

    @property
    def name(self) -> str:
        return Path(self.folder).name

    @property
    def sha256(self) -> str:
        return folder_hash(Path(self.folder))


def check_aircraft_folder(folder: str | Path) -> Path:
    """Validate that ``folder`` holds ``<name>.xml`` with an ``<fdm_config>`` root."""
    f = Path(folder)
    if not f.is_dir():
        raise UserError(f"{f}: aircraft folder not found")
    xml = f / f"{f.name}.xml"
    if not xml.is_file():
        raise UserError(f"{f}: aircraft file {xml.name} not found in the folder")
    bad = unsafe_folder(f)
    if bad:
        raise UserError(f"{bad[0]}: {bad[1]}")
    try:
        root = ET.parse(xml).getroot()
    except ET.ParseError as exc:
        raise UserError(f"{xml}: not well-formed XML ({exc})") from None
    if root.tag != "fdm_config":
        raise UserError(f"{xml}: root element: expected <fdm_config>, found <{root.tag}>")
    if root.find("aerodynamics") is None:
        raise UserError(f"{xml}: <aerodynamics>: missing")
    return f.resolve()


def merged_xml(source: AircraftSource) -> str:
    """The aircraft XML with the overlay merged and network I/O removed."""
    xml = Path(source.folder) / f"{source.name}.xml"
    tree = ET.parse(xml)
    root = tree.getroot()
    for tag in ("input", "output"):
        for el in root.findall(tag):
            root.remove(el)
    aero = root.find("aerodynamics")
    existing = {fn.get("name") for fn in aero.iter("function")}
    axes = {a.get("name"): a for a in aero.findall("axis")}
    for axis_name, text in source.effects.functions:
        fn = ET.fromstring(text)
        if fn.get("name") in existing:
            raise UserError(f"{source.effects.path}: function {fn.get('name')!r} already exists in {xml.name}")
        axis = axes.get(axis_name)
        if axis is None:
            axis = ET.SubElement(aero, "axis", {"name": axis_name})
            axes[axis_name] = axis
        axis.append(fn)
    return ET.tostring(root, encoding="unicode", xml_declaration=True)


def prepare(source: AircraftSource, root: Path | None = None) -> Path:
    """Write a private JSBSim root holding the merged aircraft.

    Parameters
    ----------
    source : AircraftSource
    root : Path, optional
        Where to write; a new temporary folder by default.

    Returns
    -------
    Path
        The JSBSim root: ``root/aircraft/<name>/<name>.xml``.
    """
    root = Path(root) if root else owned_tmpdir()
    dest = root / "aircraft" / source.name
    if dest.exists():
        shutil.rmtree(dest)
    shutil.copytree(source.folder, dest, ignore=shutil.ignore_patterns("effects", "__pycache__"))
    (dest / f"{source.name}.xml").write_text(merged_xml(source))
    return root


_TO_IN = {"IN": 1.0, "FT": 12.0, "M": 39.37007874015748, "CM": 0.3937007874015748, "MM": 0.03937007874015748}


@lru_cache(maxsize=8)
def thruster_z_in(source: AircraftSource) -> float | None:
    """Mean structural z of the thrusters in the aircraft XML [in], or None."""
    root = ET.parse(Path(source.folder) / f"{source.name}.xml").getroot()
    zs = []
    for loc in root.findall("propulsion/engine/thruster/location"):
        z = loc.find("z")
        if z is not None:
            zs.append(float(z.text) * _TO_IN.get(loc.get("unit", "IN").upper(), 1.0))
    return sum(zs) / len(zs) if zs else None
