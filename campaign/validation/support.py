"""Small shared helpers for the tests and the benchmarks."""

from __future__ import annotations

import numpy as np


#: Gear-up 2-3-1-1s at three conditions, a gear-down one at flap 30 (the diagnosis matrix's
#: conditions), and a full-circle level turn at Mach 0.3 and 10,000 ft.
TURN_MATRIX = (
    'name = "turn"\n'
    '[[points]]\ngear = "up"\nflap_deg = 0\nmach = 0.3\nalt_ft = 2000\n'
    '[[points]]\ngear = "up"\nflap_deg = 0\nmach = 0.3\nalt_ft = 10000\nmaneuvers = ["doublet", "level_turn"]\n'
    '[[points]]\ngear = "up"\nflap_deg = 0\nmach = 0.5\nalt_ft = 10000\n'
    '[[points]]\ngear = "down"\nflap_deg = 30\nmach = 0.2\nalt_ft = 2000\n'
)


def _toml_value(v) -> str:
    return "[" + ", ".join(_toml_value(x) for x in v) + "]" if isinstance(v, (list, tuple)) else repr(v)


def matrix_toml(points, name: str = "test", header: str = "") -> str:
    """A test-matrix TOML from ``(gear, flap_deg, mach, alt_ft)`` rows (mach, alt_ft may be lists)."""
    rows = [
        f'[[points]]\ngear = "{g}"\nflap_deg = {f}\nmach = {_toml_value(m)}\nalt_ft = {_toml_value(a)}'
        for g, f, m, a in points
    ]
    return f'name = "{name}"\n{header}' + "\n".join(rows) + "\n"


def pairs(*conditions) -> list[tuple]:
    """Each ``(flap_deg, mach, alt_ft)`` condition flown gear up and gear down."""
    return [(g, f, m, a) for f, m, a in conditions for g in ("up", "down")]


def z_scores(clean_fits, noisy_fits) -> np.ndarray:
    """|noisy - noise-free| / standard error, for every parameter both fits identified."""
    clean = {f.point: f for f in clean_fits}
    z = []
    for f in noisy_fits:
        for c, res in f.fits.items():
            ref = clean[f.point].fits[c]
            z += [(res.params[k] - ref.params[k]) / res.bse[k] for k in res.params.index if k in ref.params.index]
    return np.abs(np.array(z))


def run_matrix(folder, text: str, aircraft: str, effects=None, noise: str = "none", seed: int = 0, jobs: int = 2):
    """Fly a matrix (TOML text) on an aircraft folder into ``folder/data``; return that folder."""
    from pathlib import Path

    from campaign.simulation.aircraft import AircraftSource, load_effects
    from campaign.simulation.engine import FlightConfig
    from campaign.simulation.matrix import load_matrix
    from campaign.orchestration.runner import run_campaign

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "m.toml").write_text(text)
    m = load_matrix(folder / "m.toml")
    cfg = FlightConfig(
        AircraftSource(str(aircraft), load_effects(effects)), seed, noise, m.maneuver_params, m.clmax_by_flap
    )
    run_campaign(m, cfg, folder / "data", jobs=jobs, progress=False)
    return folder / "data"


def scaled_copy(aircraft, root, function: str, scale: float):
    """A copy of a JSBSim aircraft folder with one of its aero functions scaled (0: removed)."""
    import shutil
    import xml.etree.ElementTree as ET
    from pathlib import Path

    aircraft = Path(aircraft)
    dest = Path(root) / aircraft.name
    shutil.copytree(aircraft, dest)
    tree = ET.parse(dest / f"{aircraft.name}.xml")
    for axis in tree.getroot().find("aerodynamics").findall("axis"):
        for fn in axis.findall("function"):
            if fn.get("name") == function:
                if scale == 0:
                    axis.remove(fn)
                else:
                    body = [c for c in fn if c.tag != "description"]
                    for c in body:
                        fn.remove(c)
                    prod = ET.SubElement(fn, "product")
                    ET.SubElement(prod, "value").text = repr(float(scale))
                    prod.extend(body)
                tree.write(dest / f"{aircraft.name}.xml")
                return dest
    raise KeyError(f"{aircraft.name}: no aero function {function}")


def one_line_error(capsys, argv, *needles) -> str:
    """Run the CLI: exit code 2, one line on stderr holding every needle, no traceback."""
    from campaign.cli import main

    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err
    return err


#: Flap 5 at 5,000 ft and four Mach numbers close together, gear up and down, with the gear extension
#: only: a matrix whose narrow Mach range leaves rival readings apart for :mod:`campaign.design.plan`.
NARROW = matrix_toml(
    pairs((5, [0.25, 0.3, 0.35, 0.4], 5000)), "narrow", '[defaults]\nmaneuvers_gear_down = ["gear_extension"]\n'
)
