"""The layout is the design: one package per job, data flowing one way, functions a person can read."""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("infra", "maneuvers", "campaign", "identify", "diagnose")


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for f in sorted((ROOT / pkg).rglob("*.py")):
            parts = f.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = f
    return out


def _imports(path: Path, module: str, known: set[str]) -> set[str]:
    """The project's modules ``path`` imports, at module level or inside functions."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = module.split(".")[: len(module.split(".")) - node.level + (path.name == "__init__.py")]
                base = ".".join(pkg + ([base] if base else []))
            names = [base] + [f"{base}.{a.name}" for a in node.names]
        else:
            continue
        for n in names:
            while n and n not in known:
                n = n.rpartition(".")[0]
            if n and n != module:
                out.add(n)
    return out


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    return {m: _imports(p, m, set(mods)) for m, p in mods.items()}


def test_no_function_is_more_complex_than_a_person_reads():
    """The cap is on each function (McCabe complexity, arguments), not on a module's length: ruff checks it
    with the caps of pyproject.toml."""
    lint = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["ruff"]["lint"]
    assert {"C901", "PLR0913"} <= set(lint["select"])
    assert lint["mccabe"]["max-complexity"] <= 20 and lint["pylint"]["max-args"] <= 12
    ruff = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    if ruff is None:
        pytest.skip("ruff is not installed (the test extra installs it)")
    out = subprocess.run(
        [ruff, "check", "--select", "C901,PLR0913", "--output-format", "concise", "."],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stdout


def test_identify_never_imports_diagnose_or_campaign():
    graph = _graph()
    wrong = {
        m: sorted(d for d in deps if d.split(".")[0] in ("diagnose", "campaign"))
        for m, deps in graph.items()
        if m.split(".")[0] == "identify"
    }
    assert not any(wrong.values()), wrong


def test_diagnose_never_flies():
    """The diagnosis reads logs and evaluates the model; flying replays is the campaign's."""
    graph = _graph()
    wrong = {
        m: sorted(d for d in deps if d.split(".")[0] in ("campaign", "maneuvers"))
        for m, deps in graph.items()
        if m.split(".")[0] == "diagnose"
    }
    assert not any(wrong.values()), wrong


def test_no_circular_imports():
    graph = _graph()
    state: dict[str, int] = {}
    cycles = []

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                cycles.append(path[path.index(d) :] + [d] if d in path else [m, d])
            elif d not in state:
                visit(d, path + [d])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    # a package's __init__ re-exporting its own modules is not a cycle between jobs
    cycles = [c for c in cycles if not all(x.split(".")[:2] == c[0].split(".")[:2] for x in c)]
    assert not cycles, cycles


def test_infra_imports_no_science():
    """The process pool and model loading stand apart: they import none of the jobs above them."""
    graph = _graph()
    wrong = {
        m: sorted(d for d in deps if d.split(".")[0] != "infra")
        for m, deps in graph.items()
        if m.split(".")[0] == "infra"
    }
    assert not any(wrong.values()), wrong


def test_packages_follow_the_flow():
    """maneuvers <- campaign's flying; identify <- diagnose; nothing below imports what is above it."""
    graph = _graph()
    rank = {"maneuvers": 0, "identify": 1, "diagnose": 2}
    wrong = [
        (m, d)
        for m, deps in graph.items()
        for d in deps
        if m.split(".")[0] in rank and d.split(".")[0] in rank and rank[d.split(".")[0]] > rank[m.split(".")[0]]
    ]
    assert not wrong, wrong
