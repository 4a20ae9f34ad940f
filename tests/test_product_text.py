"""The product speaks to its users: no development history in code, docs, tests or benchmarks, a
README a newcomer reads in ten minutes, and the README's commands and table in step with the tree."""

from __future__ import annotations

import importlib.util
import re
import shlex
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: What development history looks like in text: a work session's number, an issue's number.
HISTORY = re.compile(r"\bstops? [0-9]+\b|since stop|until stop|\bissue [0-9]+\b", re.IGNORECASE)
#: Where the product's text lives (outputs are produced by the code, so the code covers them).
SCANNED = (
    "README.md",
    "mkdocs.yml",
    "pyproject.toml",
    "campaign",
    "identify",
    "diagnose",
    "maneuvers",
    "infra",
    "aircraft",
    "docs",
    "tests",
    "benchmarks",
    ".ci",
)
SUFFIXES = {".py", ".md", ".toml", ".xml", ".yml", ".yaml", ".csv", ".json", ".txt", ".cfg", ""}
SKIPPED = {"__pycache__", "generated", ".venv", "site"}
#: This file holds the pattern and examples of what it finds.
SELF = Path(__file__).resolve()


def _load(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _files():
    for entry in SCANNED:
        p = ROOT / entry
        paths = [p] if p.is_file() else sorted(q for q in p.rglob("*") if q.is_file())
        for q in paths:
            if q.suffix in SUFFIXES and not SKIPPED & set(q.relative_to(ROOT).parts) and q.resolve() != SELF:
                yield q


def test_no_development_history_in_the_product():
    hits = []
    for f in _files():
        try:
            text = f.read_text()
        except UnicodeDecodeError:
            continue
        for n, line in enumerate(text.splitlines(), 1):
            if HISTORY.search(line):
                hits.append(f"{f.relative_to(ROOT)}:{n}: {line.strip()[:100]}")
    assert not hits, f"{len(hits)} lines of development history:\n" + "\n".join(hits)


def test_the_pattern_finds_what_it_is_for():
    for text in ("since stop 44 the rule", "(stop 72)", "Stops 69-72", "against the targets of issue 12"):
        assert HISTORY.search(text), text
    for text in ("the stop-watch", "stop the run", "an issue with the data", "a 12-stop sweep"):
        assert not HISTORY.search(text), text


def test_the_readme_is_read_in_ten_minutes():
    assert len((ROOT / "README.md").read_text().splitlines()) <= 400


def test_the_readme_s_validation_table_is_what_the_results_give():
    tables = _load(ROOT / "benchmarks" / "tables.py", "tables")
    text = (ROOT / "README.md").read_text()
    assert tables.readme_with_table(text) == text, "run python benchmarks/tables.py"


def test_the_readme_s_commands_are_found_and_their_files_exist():
    check = _load(ROOT / ".ci" / "readme_check.py", "readme_check")
    text = (ROOT / "README.md").read_text()
    cmds = check.commands(text)
    assert cmds[0].startswith("python3 -m venv .venv") and cmds[0].endswith("campaign run --jobs 2"), cmds[0]
    python = [c for c in cmds if c.startswith("python - <<")]
    assert len(python) == 1 and "import gearaero" in python[0]  # the Python example runs too
    cmds = [c for c in cmds if c not in python]
    names = {shlex.split(c)[0] for c in cmds[1:]}
    assert names <= {".", "campaign"}, names
    subcommands = {shlex.split(c)[1] for c in cmds if c.startswith("campaign ")}
    assert {"fly", "plots", "report", "import", "identify", "run", "diagnose", "plan"} <= subcommands
    for c in cmds:
        for word in shlex.split(c):
            if word.startswith(("docs/", "tests/data/", "aircraft/")):
                assert (ROOT / word).exists(), (word, c)
    # the test command the README gives is the one CI runs, and the check does not run it itself
    skipped = text.split(check.SKIP)[1].split("```sh\n")[1].split("\n```")[0].strip()
    assert skipped in (ROOT / ".ci" / "run").read_text()
    assert skipped not in cmds


def test_the_commands_parser_joins_continuations_and_skips_what_is_marked():
    check = _load(ROOT / ".ci" / "readme_check.py", "readme_check")
    text = (
        "x\n```sh\n# a comment\ncampaign run \\\n    --jobs 2\n\ncampaign report r\n```\n"
        f"{check.SKIP} (why) -->\n```sh\ncampaign points\n```\n```python\nprint(1)\n```\n"
    )
    assert check.commands(text) == [
        "campaign run --jobs 2",
        "campaign report r",
        "python - <<'PYTHON'\nprint(1)\nPYTHON",
    ]
