"""What an aircraft supports, checked before the first flight: the effect overlay merged into it
and the weights the matrix asks of it.

JSBSim takes an overlay that reads a property nothing defines, runs it, and throws as the model is
destroyed, which aborts the process; it refuses a function named after one of the model's own
properties without naming the overlay. Both are checked here against the bare model's property
catalog, and the merged model is loaded and run once, each failure named by the overlay file and
its function.
"""

from __future__ import annotations

from campaign.errors import UserError
from campaign.simulation import catalog as cat
from campaign.simulation.aircraft import AircraftSource, Effects, overlay_reads
from campaign.simulation.engine import WEIGHT_TOLERANCE, new_fdm
from infra.model import abandon, captured_stdout

#: The initial condition the checks run the model at (the flap schedule's too).
CHECK_IC = {"ic/h-sl-ft": 5000.0, "ic/vt-kts": 200.0}


def bare(source: AircraftSource) -> AircraftSource:
    """The same aircraft without its overlay."""
    return AircraftSource(source.folder, Effects(None, ()))


def _run_ic(fdm, what: str) -> None:
    """Run the model's initial condition once; JSBSim's exception as a UserError naming ``what``."""
    for k, v in CHECK_IC.items():
        fdm[k] = v
    try:
        with captured_stdout():
            fdm.run_ic()
            fdm.run()
    except RuntimeError as exc:
        abandon(fdm)
        raise UserError(f"{what}: {' '.join(str(exc).split())}") from None


def check_overlay(source: AircraftSource) -> None:
    """Refuse, naming the overlay file and function, an overlay the aircraft cannot fly with.

    Raises
    ------
    UserError
        A function named after a property the aircraft has already, one that reads a property
        neither the aircraft nor the overlay defines, or an overlay JSBSim will not load or run.
    """
    fx = source.effects
    if not fx.functions:
        return
    names = cat.catalog_names(new_fdm(bare(source)))  # the aircraft's own faults are named by its folder
    for fn, prop in overlay_reads(fx):
        if prop not in names:
            raise UserError(
                f'{fx.path}: <function name="{fn}">: reads {prop}, a property aircraft {source.name} does not have'
            )
    for fn in (f for f in (_name(text) for _, text in fx.functions) if f in names):
        raise UserError(
            f'{fx.path}: <function name="{fn}">: {fn} is a property of aircraft {source.name} '
            f"already (an overlay adds functions of its own; name it aero/<something new>)"
        )
    try:
        fdm = new_fdm(source)
    except UserError as exc:
        said = str(exc).split(f"JSBSim could not load aircraft {source.name}", 1)[-1].lstrip(": ")
        raise UserError(
            f"{fx.path}: JSBSim will not load aircraft {source.name} with this overlay{': ' + said if said else ''}"
        ) from None
    _run_ic(fdm, f"{fx.path}: JSBSim cannot run aircraft {source.name} with this overlay")


def _name(text: str) -> str:
    import xml.etree.ElementTree as ET

    return ET.fromstring(text).get("name", "")


def check_weights(source: AircraftSource, weights: list[tuple[str, float]]) -> None:
    """Refuse, naming the field, a gross weight the aircraft cannot be loaded to.

    Parameters
    ----------
    weights : list of (where, weight [lb])
        ``where`` names the input field, e.g. ``"m.toml: points[3].weight_lb"``.
    """
    if not weights:
        return
    fdm = new_fdm(source)
    names = cat.catalog_names(fdm)
    _run_ic(fdm, f"{source.folder}: JSBSim cannot run aircraft {source.name}")
    own = fdm["inertia/weight-lbs"]
    if cat.POINTMASS_WEIGHT in names:
        lightest = own - fdm[cat.POINTMASS_WEIGHT]
        for where, w in weights:
            if w < lightest - 1.0:
                raise UserError(
                    f"{where}: {w:g} lb is below aircraft {source.name}'s empty weight and fuel ({lightest:.0f} lb)"
                )
        return
    for where, w in weights:
        if abs(own - w) > WEIGHT_TOLERANCE * own:
            raise UserError(
                f"{where}: aircraft {source.name} has no point mass to set the weight with "
                f"(it weighs {own:.0f} lb; leave weight_lb out to fly it so)"
            )
