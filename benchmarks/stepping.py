"""Steps per second of the campaign's flying loop against raw ``fdm.run()``.

Run: ``python benchmarks/stepping.py`` (one process, one core). Both are measured
on the same trimmed aircraft in the same process; the flying loop includes the
autopilot hold, control writes and reading every logged channel. Then where a step
goes, the floor of any loop that logs through JSBSim's Python API, and what JSBSim's
own logging (its CSV output, no Python per step) costs a step.
"""

from __future__ import annotations

import array
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("JSBSIM_DEBUG", "0")

from campaign.simulation import catalog as cat  # noqa: E402
from campaign.simulation.aircraft import DEFAULT_AIRCRAFT, DEFAULT_EFFECTS, AircraftSource, load_effects  # noqa: E402
from campaign.simulation.engine import (  # noqa: E402
    FlightConfig,
    flap_schedule,
    fly,
    model_catalog,
    new_fdm,
    trim,
    trimmed_fdm,
)
from campaign.simulation.matrix import load_matrix  # noqa: E402
from maneuvers.autopilot import HoldAutopilot, HoldGains  # noqa: E402


def main(repeats: int = 5) -> None:
    m = load_matrix()
    cfg = FlightConfig(
        AircraftSource(str(DEFAULT_AIRCRAFT), load_effects(DEFAULT_EFFECTS)),
        maneuver_params=m.maneuver_params,
        clmax_by_flap=m.clmax_by_flap,
    )
    point = m.point("h02000_m0.30_f05_gdn")
    fly(point, "gear_extension", cfg)  # warm the caches (prepared aircraft, elevator gain)

    fdm, *_ = trimmed_fdm(cfg.aircraft, point, 0.0)
    n = 20000
    raw = []
    for _ in range(repeats):
        t = time.perf_counter()
        for _ in range(n):
            fdm.run()
        raw.append(n / (time.perf_counter() - t))

    ours = []
    for _ in range(repeats):
        t = time.perf_counter()
        flight = fly(point, "gear_extension", cfg)  # includes model load and trim
        ours.append(len(flight.log) / (time.perf_counter() - t))

    setup = []
    for _ in range(repeats):
        t = time.perf_counter()
        trimmed_fdm(cfg.aircraft, point, 0.0)
        setup.append(time.perf_counter() - t)
    t = time.perf_counter()
    flight = fly(point, "gear_extension", cfg)
    total = time.perf_counter() - t
    loop_only = len(flight.log) / (min(len(flight.log) / r for r in ours) - min(setup))
    print(f"raw fdm.run():                 {max(raw):9.0f} steps/s (best of {repeats})")
    print(f"flying loop (hold + logging):  {max(ours):9.0f} steps/s incl. load+trim (best of {repeats})")
    print(f"flying loop alone:             {loop_only:9.0f} steps/s (load+trim {min(setup) * 1000:.0f} ms subtracted)")
    print(f"ratio loop/raw:                {loop_only / max(raw):9.2f}")
    print(
        f"one gear extension ({len(flight.log)} steps, {len(flight.log) / 120:.1f} s simulated): "
        f"{total * 1000:.0f} ms wall"
    )
    breakdown(fdm, max(raw), loop_only, n)
    props = [p for p, _ in cat.STATE_CHANNELS.values()] + list(cat.FORCE_CHANNELS.values())
    native = jsbsim_logging(cfg.aircraft, point, props, n)
    print(
        f"\nJSBSim logging the same {len(props)} properties itself (its CSV output every frame, no Python "
        f"per step): {native:.1f} us a step, ratio {1e6 / max(raw) / native:.2f}"
    )


def breakdown(fdm, raw: float, loop: float, n: int) -> None:
    """Where a step of the flying loop goes: raw stepping, then the property writes and reads
    the loop makes through JSBSim's Python API, each timed alone on the same aircraft."""
    pm = fdm.get_property_manager()
    reads = [pm.get_node(p, False) for p, _ in cat.STATE_CHANNELS.values()]
    reads += [pm.get_node(p, False) for p in cat.FORCE_CHANNELS.values()]
    writes = [
        pm.get_node(p, False)
        for p in (
            cat.CONTROLS["elevator"],
            cat.CONTROLS["pitch_trim"],
            cat.CONTROLS["gear_cmd"],
            cat.CONTROLS["throttle"].format(i=0),
            cat.CONTROLS["throttle"].format(i=1),
        )
    ]
    t = time.perf_counter()
    for _ in range(n):
        for node in reads:
            node.get_double_value()
    read_us = (time.perf_counter() - t) / n * 1e6
    t = time.perf_counter()
    for _ in range(n):
        for node in writes:
            node.set_double_value(node.get_double_value())
    write_us = (time.perf_counter() - t) / n * 1e6
    step_us, raw_us = 1e6 / loop, 1e6 / raw
    run = fdm.run
    get = type(reads[0]).get_double_value
    floor_us = float("inf")
    for _ in range(3):
        buf = array.array("d")
        t = time.perf_counter()
        for _ in range(n):
            run()
            buf.extend(map(get, reads))
        floor_us = min(floor_us, (time.perf_counter() - t) / n * 1e6)
    print(
        f"\nthe floor of any loop that logs through the Python API: fdm.run() and the {len(reads)} logged "
        f"properties appended to a flat buffer (as the engine does), nothing else: {floor_us:.1f} us a step "
        f"(best of 3), "
        f"ratio {raw_us / floor_us:.2f}"
    )
    hold = HoldAutopilot(HoldGains(), 1.0 / 120.0, 2000.0, 330.0, 2.0, -1.0, 0.5, 130.0)
    t = time.perf_counter()
    for _ in range(n):
        hold.step(2000.1, 0.1, 330.2, 2.01, 0.01)
    hold_us = (time.perf_counter() - t) / n * 1e6
    print(
        f"\nper step [us]: loop {step_us:.1f} = raw fdm.run() {raw_us:.1f} + {len(reads)} property reads "
        f"{read_us:.1f} + {len(writes)} control writes {write_us:.1f} + the rest (the hold's update alone "
        f"{hold_us:.1f}, gusts, the row, Python) {step_us - raw_us - read_us - write_us:.1f}"
    )
    print(
        f"a loop at 0.85 of raw may add {raw_us / 0.85 - raw_us:.1f} us a step to fdm.run(): less than the "
        f"reads alone cost through the Python API"
    )


def jsbsim_logging(source, point, props: list[str], n: int) -> float:
    """Microseconds a step of ``fdm.run()`` with JSBSim itself logging ``props`` every frame: its own
    CSV output (``<output type="CSV">``, 18 significant digits a value), the one way JSBSim writes a
    log without a Python call per step."""
    with tempfile.TemporaryDirectory() as d:
        xml = Path(d) / "output.xml"
        items = "".join(f"  <property>{p}</property>\n" for p in props)
        xml.write_text(
            f'<?xml version="1.0"?>\n<output name="{Path(d) / "log.csv"}" type="CSV" rate="120">\n{items}</output>\n'
        )
        names, n_eng, _ = model_catalog(source)
        fdm = new_fdm(source)
        if not fdm.set_output_directive(str(xml)):
            raise RuntimeError("JSBSim refused the output directive")
        trim(fdm, point, 0.0, flap_schedule(source).command_for(point.flap_deg), n_eng, names)
        best = float("inf")
        for _ in range(3):
            t = time.perf_counter()
            for _ in range(n):
                fdm.run()
            best = min(best, (time.perf_counter() - t) / n * 1e6)
        if not (Path(d) / "log.csv").stat().st_size:
            raise RuntimeError("JSBSim wrote no log")
        del fdm  # closes the file before the folder goes
    return best


if __name__ == "__main__":
    main()
