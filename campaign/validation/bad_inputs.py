"""Generated bad inputs for the command line, and the check each must pass: exit code 2, one line on
stderr naming the file and the field (or the option), no traceback, nothing on disk changed.

Six kinds, each a valid input with one thing made wrong at random: test matrices, import maps, measured
data files, instrument profiles, effect overlays and command lines. :func:`make_cases` writes each
case's files into a folder of its own; :func:`attempt` runs the CLI's ``main()`` in this process on it.
``benchmarks/bad_input_sweep.py`` runs a thousand and more; the test suite a few dozen.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import random
import traceback
from dataclasses import dataclass
from pathlib import Path

KINDS = ("matrix", "map", "data", "profile", "overlay", "cli")

MATRIX = """name = "sweep"
[maneuvers.doublet]
tail_s = 1.0
[[points]]
gear = "up"
flap_deg = 0
mach = 0.3
alt_ft = 2000
"""
OVERLAY = (
    '<effects><axis name="DRAG"><function name="aero/sweep-extra"><product><property>aero/qbar-psf'
    "</property><value>0.0001</value></product></function></axis></effects>\n"
)
#: The columns of the HFB-320 record the shipped map reads (index, name).
MAPPED = (
    (0, "t"),
    (1, "de"),
    (2, "qbar"),
    (3, "Fe"),
    (4, "V"),
    (5, "alpha"),
    (6, "theta"),
    (7, "q"),
    (8, "qdot"),
    (9, "ax"),
    (10, "az"),
    (11, "ay"),
    (12, "p"),
    (13, "r"),
    (16, "beta"),
    (17, "phi"),
)


@dataclass(frozen=True)
class Case:
    """One bad input: the command line, and what its one line must name."""

    kind: str
    label: str
    argv: tuple[str, ...]
    needles: tuple[str, ...]  # each must be in the line ("a|b": a or b)

    @property
    def sha256(self) -> str:
        """Of the command line and the bytes of every file it names that this case wrote."""
        h = hashlib.sha256("\0".join(self.argv).encode())
        for a in self.argv:
            p = Path(a)
            if p.is_file() and "case-" in a:
                h.update(p.read_bytes())
        return h.hexdigest()


def _num(rng: random.Random, kind: str) -> str:
    """A TOML number of a kind: ``bad`` (not finite), ``neg``, ``huge``, ``text``."""
    if kind == "bad":
        return rng.choice(["nan", "inf", "-inf", "+nan"])
    if kind == "neg":
        return f"{-rng.uniform(0.001, 1e4):.6g}"
    if kind == "huge":
        return f"{rng.uniform(1, 9):.3f}e{rng.randint(6, 300)}"
    return rng.choice(['"fast"', "true", "[]", "{}", '"1,5"', '""'])


def _matrix(rng: random.Random, d: Path, ctx: dict) -> Case:
    c = rng.choice

    def num(*kinds: str) -> str:
        return _num(rng, c(kinds))

    edits = [
        ("mach", "mach = 0.3", lambda: c([num("bad", "neg", "huge", "text"), "0", "[]", f"{rng.uniform(1, 5):.3f}"])),
        ("alt_ft", "alt_ft = 2000", lambda: c([num("bad", "huge", "text"), f"{-rng.uniform(1001, 1e5):.0f}", "[]"])),
        ("flap_deg", "flap_deg = 0", lambda: c([num("bad", "huge", "text"), f"{rng.uniform(91, 500):.1f}", "45"])),
        ("gear", 'gear = "up"', lambda: c(["'sideways'", "1", "true", "''", "'UP'"])),
        ("weight_lb", None, lambda: c([num("bad", "neg", "huge", "text"), "0", f"{rng.uniform(1, 99):.1f}"])),
        (
            "maneuvers",
            None,
            lambda: c(["[]", "['loop']", "['doublet', 'doublet']", "'doublet'", "[1]", "['doublet', 'multisine']"]),
        ),
        ("maneuvers_gear_up", "", lambda: c(["[]", "['loop']", "'doublet'"])),
        ("tail_s", "tail_s = 1.0", lambda: c([num("bad", "neg", "huge", "text"), "0", f"{rng.uniform(601, 1e5):.0f}"])),
        ("amplitude_deg", "", lambda: c([num("bad", "neg", "text"), "0", f"{rng.uniform(10.5, 90):.1f}"])),
        ("turn_s", "", lambda: c([num("bad", "neg", "text"), "0", f"{rng.uniform(601, 1e5):.0f}"])),
        (
            "clmax_by_flap",
            "",
            lambda: c(["0 = -1", "0 = nan", "0 = 'x'", f"0 = {rng.uniform(5.1, 99):.2f}", "x = 1.4", "0 = 0"]),
        ),
        ("colour", "", lambda: str(rng.randint(0, 9))),
        ("name", 'name = "sweep"', lambda: c(["'../x'", "''", "5", "'/abs'", "'.hidden'"])),
        ("TOML", "[[points]]", lambda: c(["[[points]", "[[points]]]", "[[points"])),
    ]
    field, old, value = edits[rng.randrange(len(edits))]
    v = value()
    if field == "TOML":
        text = MATRIX.replace(old, v)
    elif old is None:  # a key of the point
        text = MATRIX + f"{field} = {v}\n"
    elif field == "maneuvers_gear_up":
        text = f"[defaults]\n{field} = {v}\n" + MATRIX.replace('name = "sweep"\n', "")
    elif field == "amplitude_deg":
        text = MATRIX.replace("tail_s = 1.0", f"tail_s = 1.0\namplitude_deg = {v}")
    elif field == "turn_s":
        text = MATRIX + f"[maneuvers.level_turn]\nturn_s = {v}\n"
    elif field == "clmax_by_flap":
        text = MATRIX + f"[stall.clmax_by_flap]\n{v}\n"
    elif field == "colour":
        text = MATRIX.replace('name = "sweep"', f'name = "sweep"\ncolour = {v}')
    else:
        text = MATRIX.replace(old, f"{old.split(' = ')[0]} = {v}")
    f = _write(d / "matrix.toml", text)
    command = "run" if v == "45" else c(["run", "run", "points", "fly"])  # flap 45: the aircraft's to refuse
    if command == "points":
        argv = ["points", "--matrix", str(f)]
    elif command == "fly":
        argv = ["fly", "h02000_m0.30_f00_gup", "--matrix", str(f), "--out", str(d / "out")]
    else:
        argv = ["run", "--matrix", str(f), "--out", str(d / "out"), "--quiet", "--effects", "none"]
    return Case("matrix", f"matrix: {field}", tuple(argv), ("matrix.toml", field))


_UNIT = {"S": "ft^2", "cbar": "ft", "b": "ft", "iyy": "kg*m^2", "mass": "kg"}


def _map(rng: random.Random, d: Path, ctx: dict) -> Case:
    base, c = ctx["map_text"], rng.choice

    def num(*kinds: str) -> str:
        return _num(rng, c(kinds))

    key = c(list(_UNIT))
    edits = [
        (
            f"aircraft.{key}",
            "map",
            lambda: _set_aircraft(
                base,
                key,
                c(
                    [
                        num("bad", "neg", "text"),
                        "0",
                        f"'-{rng.uniform(1, 5e3):.1f} {_UNIT[key]}'",
                        f"{rng.uniform(2e9, 9e12):.3g}",
                    ]
                ),
            ),
        ),
        (
            "constants.mass_slug",
            "map",
            lambda: base.replace(
                'mass_slug = "7472 kg"', "mass_slug = " + c([num("bad", "neg"), "'-7472 kg'", "'7472 m'"])
            ),
        ),
        (
            "channels.alpha_deg",
            "map",
            lambda: base.replace(
                'alpha_deg = "alpha rad"', "alpha_deg = " + c(["'alpha furlong'", "'alpha'", "5", "''", "'alpha kg'"])
            ),
        ),
        ("channels.alpha_deg", "data", lambda: base.replace('alpha_deg = "alpha rad"', "alpha_deg = 'qbar rad'")),
        (
            "time.unit",
            "map",
            lambda: base.replace('unit = "s"', "unit = " + c(["'h'", "'us'", "'kg'", "'furlong'", "'ns'", "'day'"])),
        ),
        ("time.column", "data", lambda: base.replace('column = "t"', "column = " + c(["'nosuch'", "'T'", "'time'"]))),
        (
            "positions.alpha_deg",
            "map",
            lambda: base + f"\n[positions]\nalpha_deg = [{rng.uniform(501, 1e6):.1f}, 0, 0]\n",
        ),
        ("positions.q_dps", "map", lambda: base + "\n[positions]\nq_dps = [1.0, 0, 0]\n"),
        (
            "source.format",
            "map",
            lambda: base.replace('format = "whitespace"', "format = " + c(["'xlsx'", "'hdf5'", "'CSV'"])),
        ),
        ("colour", "map", lambda: base + f"\n[colour]\nred = {rng.randint(0, 9)}\n"),
    ]
    field, names, make = c(edits)
    f = _write(d / "map.toml", make())
    named = Path(ctx["data"]).name if names == "data" else "map.toml"
    return Case("map", f"map: {field}", _import(ctx["data"], f, d), (named, field))


def _set_aircraft(text: str, key: str, value: str) -> str:
    head, sep, rest = text.partition("[aircraft]")
    lines = [ln for ln in rest.splitlines() if ln.split("=")[0].strip() != key]
    return head + sep + "\n".join(lines[:1] + [f"{key} = {value}"] + lines[1:]) + "\n"


def _import(data, mapf, d: Path) -> tuple[str, ...]:
    return ("import", str(data), "--map", str(mapf), "--out", str(d / "out"))


def _data(rng: random.Random, d: Path, ctx: dict) -> Case:
    rows = [ln.split() for ln in ctx["data_text"].splitlines() if ln.strip()]
    f = d / "flight.asc"
    pick = rng.randrange(10)
    needle = "row"
    if pick == 0:  # a cell that is not a number
        i, (j, _) = rng.randrange(len(rows)), rng.choice(MAPPED)
        rows[i][j] = rng.choice(["abc", "nan", "inf", "-inf", "1.2.3", "--", "0x1F"])
    elif pick == 1:  # time that does not increase
        i = rng.randrange(1, len(rows) - 1)
        rows[i][0] = rows[i - 1][0] if rng.random() < 0.5 else f"{float(rows[i - 1][0]) - rng.uniform(0.01, 5):.5f}"
        needle = "time"
    elif pick == 2:  # a gap
        i = rng.randrange(20, len(rows) - 40)
        del rows[i : i + rng.randint(5, 30)]
        needle = "gap"
    elif pick == 3:
        rows = rows[: rng.randint(1, 9)]
        needle = "rows"
    elif pick == 4:  # alpha in degrees where the map says radians
        for r in rows:
            r[5] = f"{float(r[5]) * 57.29578 * rng.uniform(3, 10):.5f}"
        needle = "channels.alpha_deg"
    elif pick == 5:  # negative dynamic pressure
        for r in rows:
            r[2] = f"{-abs(float(r[2])):.3f}"
        needle = "qbar_psf"
    elif pick == 6:  # a line past the length bound
        rows.insert(rng.randrange(len(rows)), ["1"] * rng.randint(600_000, 900_000))
        needle = "row"
    elif pick == 7:  # more fields than a table has
        rows.insert(rng.randrange(len(rows)), ["1"] * rng.randint(20_001, 60_000))
        needle = "fields"
    elif pick == 8:  # binary
        f.write_bytes(bytes(rng.randrange(256) for _ in range(rng.randint(64, 4096))))
        return Case("data", "data: binary", _import(f, ctx["map"], d), ("flight.asc",))
    else:
        f.write_text("" if rng.random() < 0.5 else "# only a comment\n")
        return Case("data", "data: empty", _import(f, ctx["map"], d), ("flight.asc",))
    f.write_text("\n".join(" ".join(r) for r in rows) + "\n")
    return Case("data", f"data: {needle}", _import(f, ctx["map"], d), ("flight.asc", needle))


def _profile(rng: random.Random, d: Path, ctx: dict) -> Case:
    c = rng.choice
    ch = c(["alpha_deg", "q_dps", "tas_kt", "theta_deg", "az_fps2", "elevator_deg"])

    def num(*kinds: str) -> str:
        return _num(rng, c(kinds))

    edits = [
        (
            "rate_hz",
            lambda: (
                "rate_hz = "
                + c(
                    [
                        num("bad", "neg", "huge", "text"),
                        "0",
                        f"{rng.uniform(120.5, 1e5):.1f}",
                        f"{rng.uniform(0.001, 4.9):.3f}",
                    ]
                )
            ),
        ),
        (
            f"channels.{ch}.scale",
            lambda: (
                f"[channels.{ch}]\nscale = "
                + c(
                    [
                        num("bad", "neg", "huge", "text"),
                        "0",
                        f"{rng.uniform(2.01, 100):.2f}",
                        f"{rng.uniform(0.0, 0.49):.3f}",
                    ]
                )
            ),
        ),
        (
            f"channels.{ch}.delay_s",
            lambda: (
                f"[channels.{ch}]\ndelay_s = " + c([num("bad", "neg", "huge", "text"), f"{rng.uniform(5.1, 1e7):.1f}"])
            ),
        ),
        (
            f"channels.{ch}.lag_s",
            lambda: (
                f"[channels.{ch}]\nlag_s = " + c([num("bad", "neg", "huge", "text"), f"{rng.uniform(5.1, 1e7):.1f}"])
            ),
        ),
        (f"channels.{ch}.noise", lambda: f"[channels.{ch}]\nnoise = " + num("bad", "neg", "text")),
        (f"channels.{ch}.bias", lambda: f"[channels.{ch}]\nbias = " + num("bad", "text")),
        (
            "position_ft",
            lambda: (
                "[channels.alpha_deg]\nposition_ft = "
                + c([f"[{rng.uniform(501, 1e9):.1f}, 0, 0]", "[1, 2]", "'nose'", "[nan, 0, 0]"])
            ),
        ),
        ("position_ft", lambda: "[channels.q_dps]\nposition_ft = [1.0, 0, 0]"),
        ("omit", lambda: "omit = " + c(["['alpha_deg']", "['nosuch']", "'qdot_dps2'", "[1]", "['t_s']"])),
        (
            "sigma_fps",
            lambda: (
                "[turbulence]\nsigma_fps = " + c([num("bad", "neg", "huge", "text"), f"{rng.uniform(30.5, 1e4):.1f}"])
            ),
        ),
        ("alpha_vane", lambda: "[channels.alpha_vane]\nnoise = 0.1"),
        ("extends", lambda: "extends = " + c(["'wind-tunnel'", "'flight_test'", "''", "'../none'"])),
        ("channels", lambda: "channels = 3"),
        ("colour", lambda: f"colour = {rng.randint(0, 9)}"),
    ]
    field, make = c(edits)
    parent = 'extends = "flight-test"\n' if rng.random() < 0.5 and field != "extends" else ""
    f = _write(d / "profile.toml", parent + make() + "\n")
    return Case(
        "profile",
        f"profile: {field.split('.')[-1]}",
        ("run", "--matrix", ctx["matrix"], "--instruments", str(f), "--out", str(d / "out"), "--quiet"),
        ("profile.toml", field),
    )


def _overlay(rng: random.Random, d: Path, ctx: dict) -> Case:
    fn = "aero/sweep-extra"
    edits = [
        (
            "<value>",
            lambda: OVERLAY.replace(
                ">0.0001<",
                f">{rng.choice(['nan', 'inf', '-inf', '1e400', 'abc', '', '0x10', '1,5', f'{rng.uniform(1, 9):.2f}e{rng.randint(309, 999)}'])}<",
            ),
        ),
        (
            "reads",
            lambda: OVERLAY.replace(
                ">aero/qbar-psf<",
                f">{rng.choice(['no/such/property', 'aero/qbar', 'fcs/flaps', f'aero/x{rng.randint(0, 999)}'])}<",
            ),
        ),
        ("<property>", lambda: OVERLAY.replace(">aero/qbar-psf<", f">{rng.choice(['', 'aero/qbar psf', ' '])}<")),
        (
            "already",
            lambda: OVERLAY.replace(
                fn, rng.choice(["fcs/elevator-pos-rad", "aero/qbar-psf", "velocities/mach", "aero/alpha-rad"])
            ),
        ),
        (
            "<tableData>",
            lambda: OVERLAY.replace(
                "<product><property>aero/qbar-psf</property><value>0.0001</value></product>",
                f"<table><independentVar>aero/alpha-rad</independentVar><tableData>0 0.001\n"
                f"{rng.choice(['0.1 nan', 'abc 0.002', '0.1 1e400', '0.1 inf'])}</tableData></table>",
            ),
        ),
        (
            "reads",
            lambda: OVERLAY.replace(
                "<product><property>aero/qbar-psf</property><value>0.0001</value></product>",
                "<table><independentVar>aero/nosuch-rad</independentVar><tableData>0 0.001\n0.1 0.002</tableData></table>",
            ),
        ),
        ("axis", lambda: OVERLAY.replace('name="DRAG"', f'name="{rng.choice(["UP", "drag", "", "LIFT2"])}"')),
        ("<effects>", lambda: OVERLAY.replace("effects>", "overlay>")),
        ("name", lambda: OVERLAY.replace(f' name="{fn}"', "")),
        ("exactly one", lambda: OVERLAY.replace("</product>", "</product><value>1</value>")),
        (
            "entity",
            lambda: (
                '<!DOCTYPE effects [<!ENTITY x SYSTEM "file:///etc/passwd">]>\n' + OVERLAY.replace(">0.0001<", ">&x;<")
            ),
        ),
        ("not well-formed", lambda: OVERLAY[: rng.randint(10, len(OVERLAY) - 12)]),
        (
            "appears twice",
            lambda: OVERLAY.replace("</function>", f'</function><function name="{fn}"><value>1</value></function>'),
        ),
    ]
    field, make = rng.choice(edits)
    f = d / "overlay.xml"
    f.write_text(make())
    return Case(
        "overlay",
        f"overlay: {field}",
        ("run", "--matrix", ctx["matrix"], "--effects", str(f), "--out", str(d / "out"), "--quiet"),
        ("overlay.xml", field),
    )


def _cli(rng: random.Random, d: Path, ctx: dict) -> Case:
    res, out = ctx["results"], str(d / "out")
    run = ["run", "--matrix", ctx["matrix"], "--out", out, "--quiet"]
    plan = ["plan", "--diagnosis", ctx["diagnosis"]]
    edits = [
        ("--jobs", lambda: run + ["--jobs", rng.choice(["0", "-1", "two", "1.5", ""])]),
        ("--seed", lambda: run + ["--seed", rng.choice(["x", "1.5", "", "1e3"])]),
        ("--noise", lambda: run + ["--noise", rng.choice(["loud", "", "NONE"])]),
        ("--cluster", lambda: run + ["--cluster", rng.choice(["nonsense", "http://x:1", "tcp://", "tcp://host"])]),
        (
            "--budget-min",
            lambda: plan + ["--budget-min", rng.choice(["0", "-5", "nan", "inf", "x", f"{-rng.uniform(0, 1e3):.1f}"])],
        ),
        (
            "matrix.toml",
            lambda: plan + ["--matrix", str(_write(d / "matrix.toml", MATRIX.replace("mach = 0.3", "mach = nan")))],
        ),
        (
            "--bands",
            lambda: [
                "diagnose",
                "--data",
                res,
                "--model",
                ctx["aircraft"],
                "--out",
                out,
                "--bands",
                str(rng.randint(1, 19)),
                "--quiet",
            ],
        ),
        (
            "inside --data|will not overwrite",
            lambda: [
                "diagnose",
                "--data",
                res,
                "--model",
                ctx["aircraft"],
                "--out",
                str(Path(res) / rng.choice(["d", "x/y", "."])),
                "--quiet",
            ],
        ),
        ("nowhere", lambda: [rng.choice(["identify", "report", "plots"]), str(d / "nowhere")]),
        ("nowhere", lambda: ["diagnose", "--data", str(d / "nowhere"), "--model", ctx["aircraft"], "--out", out]),
        ("manifest.json", lambda: ["replay", res]),
        ("is a file", lambda: ["import", ctx["data"], "--map", ctx["map"], "--out", str(_write(d / "afile", "x"))]),
        ("h99999_m0.30_f00_gup", lambda: ["fly", "h99999_m0.30_f00_gup", "--matrix", ctx["matrix"], "--out", out]),
        ("fly-away", lambda: ["fly-away"]),
    ]
    field, make = rng.choice(edits)
    argv = make()
    return Case("cli", f"cli: {field}", tuple(argv), (field,))


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


MAKERS = {"matrix": _matrix, "map": _map, "data": _data, "profile": _profile, "overlay": _overlay, "cli": _cli}


def context(work: Path, data: Path, map_file: Path, results: Path, aircraft: Path) -> dict:
    """What the cases start from: a valid matrix, the measured file and its map, a results folder that
    must not change, the aircraft, and a diagnosis folder for ``plan``."""
    work.mkdir(parents=True, exist_ok=True)
    matrix = _write(work / "good.toml", MATRIX)
    diag = work / "diagnosis"
    diag.mkdir(exist_ok=True)
    (diag / "diagnosis.json").write_text(json.dumps({"rivals": [], "model": str(aircraft), "data": {"paths": []}}))
    return {
        "matrix": str(matrix),
        "data": str(data),
        "data_text": Path(data).read_text(),
        "map": str(map_file),
        "map_text": Path(map_file).read_text(),
        "results": str(results),
        "aircraft": str(aircraft),
        "diagnosis": str(diag),
    }


def make_cases(ctx: dict, work: Path, n: int, seed: int = 0) -> list[Case]:
    """``n`` bad inputs, the six kinds in turn, each written into ``work/case-<i>``."""
    rng = random.Random(seed)
    out = []
    for i in range(n):
        d = Path(work) / f"case-{i:05d}"
        d.mkdir(parents=True, exist_ok=True)
        out.append(MAKERS[KINDS[i % len(KINDS)]](rng, d, ctx))
    return out


def tree_hash(folder: Path) -> str:
    """SHA-256 over the relative names, bytes and modification times of every file of a folder."""
    h = hashlib.sha256()
    for p in sorted(Path(folder).rglob("*")):
        if p.is_file():
            h.update(f"{p.relative_to(folder)}\0{p.stat().st_mtime_ns}\0".encode() + p.read_bytes())
    return h.hexdigest()


def attempt(case: Case) -> dict:
    """Run the CLI's ``main()`` in this process on one case; what the check needs of it."""
    from campaign.cli import main

    err, out = io.StringIO(), io.StringIO()
    escaped = ""
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            code = main(list(case.argv))
    except BaseException:  # noqa: BLE001 - an exception out of main is what the sweep counts
        code, escaped = None, traceback.format_exc()
    text = err.getvalue()
    out_dir = next((Path(a) for a in case.argv if a.endswith("/out")), None)
    return {
        "kind": case.kind,
        "label": case.label,
        "code": code,
        "stderr": text[-2000:],
        "one_line": text.count("\n") == 1,
        "traceback": bool(escaped) or "Traceback" in text,
        "named": all(any(alt in text for alt in n.split("|")) for n in case.needles),
        "wrote_out": bool(out_dir and out_dir.exists()),
        "escaped": escaped[-2000:],
    }


def clean(result: dict) -> bool:
    """Whether a case passed: exit 2, one line naming its file and field, no traceback, no --out written."""
    return (
        result["code"] == 2
        and result["one_line"]
        and result["named"]
        and not result["traceback"]
        and not result["wrote_out"]
    )
