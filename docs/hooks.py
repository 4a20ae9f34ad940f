"""MkDocs hooks: before each build, the pages made from data.

- ``docs/generated/*.md`` and ``*.png``: the benchmark results' tables and figures
  (:mod:`benchmarks.tables`, from ``benchmarks/results/``);
- ``docs/generated/cli.md``: every subcommand's ``--help``, from the command line's own parser;
- ``docs/generated/settings.md``: the diagnosis's decision thresholds, from
  :class:`diagnose.config.DiagnosisSettings` (each field's own documentation).
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _tables():
    spec = importlib.util.spec_from_file_location("tables", ROOT / "benchmarks" / "tables.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def cli_reference() -> str:
    """``campaign --help`` and each subcommand's, as the parser prints them."""
    sys.path.insert(0, str(ROOT))
    from campaign.cli.main import build_parser

    os.environ["COLUMNS"] = "100"
    parser = build_parser()
    out = ["```\n" + parser.format_help() + "```\n"]
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    for name, p in sub.choices.items():
        out.append(f"\n## campaign {name}\n\n```\n{p.format_help()}```\n")
    return "".join(out)


def settings_table() -> str:
    """The table of every decision threshold of the diagnosis: default, unit, what it guards, how it was
    calibrated."""
    sys.path.insert(0, str(ROOT))
    from diagnose.config import DiagnosisSettings
    from infra.settings import markdown_table

    return markdown_table(DiagnosisSettings)


def on_pre_build(config, **kwargs) -> None:
    tables = _tables()
    tables.write_docs()
    for name, text in (("cli.md", cli_reference()), ("settings.md", settings_table())):
        path = tables.GENERATED / name
        if not path.exists() or path.read_text() != text:
            path.write_text(text)
