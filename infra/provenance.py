"""The tool's name and version, as every output records them (its provenance).

The version is single-sourced in ``pyproject.toml`` and read from the installed package's
metadata (``importlib.metadata``).
"""

from __future__ import annotations

from functools import lru_cache
from importlib import metadata

#: The distribution's name (``pip install gear-aero-id``); the Python package is ``gearaero``.
NAME = "gear-aero-id"


@lru_cache(maxsize=1)
def version() -> str:
    """The installed version of :data:`NAME` ("unknown" when the sources run uninstalled)."""
    try:
        return metadata.version(NAME)
    except metadata.PackageNotFoundError:
        return "unknown"


def tool() -> dict[str, str]:
    """``{"name": ..., "version": ...}``: what each output's ``tool`` entry holds."""
    return {"name": NAME, "version": version()}


def tool_text() -> str:
    """``gear-aero-id 0.2.0``: the tool for a line of text."""
    return f"{NAME} {version()}"
