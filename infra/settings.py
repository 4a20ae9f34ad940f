"""Decision thresholds documented where they are defined.

Each threshold is a field of a frozen dataclass made by :func:`setting` (or ``dataclasses.field`` with
:func:`doc`, for a default that needs a factory), whose metadata holds its unit, what it guards and how its
value was calibrated. :func:`documented` writes the class's ``Attributes`` section from them, and
:func:`rows` and :func:`markdown_table` give the documentation's table: each field is described once.
"""

from __future__ import annotations

import dataclasses
import inspect
import textwrap
from typing import Any

#: The metadata every documented field carries (:func:`doc`).
KEYS = ("unit", "guards", "calibration")


def doc(unit: str, guards: str, calibration: str = "") -> dict[str, str]:
    """A settings field's documentation, as its metadata: ``dataclasses.field(default_factory=...,
    metadata=doc(...))`` for a default that needs a factory (a dict).

    Parameters
    ----------
    unit : str
        Its unit, ``"-"`` for a ratio or a count.
    guards : str
        The decision it takes part in, in a sentence or two.
    calibration : str
        How the value was chosen and on which data ("" where none was recorded).
    """
    return {"unit": unit, "guards": " ".join(guards.split()), "calibration": " ".join(calibration.split())}


def setting(default: Any, unit: str, guards: str, calibration: str = "") -> Any:
    """A dataclass field with an immutable ``default`` (a number, a tuple) and its documentation (:func:`doc`).

    Raises
    ------
    TypeError
        For a mutable default: that one needs ``dataclasses.field(default_factory=..., metadata=doc(...))``.
    """
    if isinstance(default, (dict, list, set)):
        raise TypeError("setting: a mutable default needs dataclasses.field(default_factory=..., metadata=doc(...))")
    return dataclasses.field(default=default, metadata=doc(unit, guards, calibration))


def _value(field: dataclasses.Field) -> Any:
    return field.default_factory() if field.default is dataclasses.MISSING else field.default


def _shown(value: Any) -> str:
    if isinstance(value, dict):
        return ", ".join(f"{k}: {v:g}" if isinstance(v, float) else f"{k}: {v}" for k, v in value.items())
    if isinstance(value, tuple):
        return ", ".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value)
    return f"{value:g}" if isinstance(value, float) else str(value)


def rows(cls: type, prefix: str = "") -> list[dict[str, str]]:
    """Each documented field of ``cls`` (a nested settings class's fields under ``<field>.``):
    ``name``, ``default``, ``unit``, ``guards``, ``calibration``."""
    out = []
    for f in dataclasses.fields(cls):
        value = _value(f)
        if dataclasses.is_dataclass(value):
            out += rows(type(value), f"{prefix}{f.name}.")
        elif "guards" in f.metadata:
            out.append({"name": prefix + f.name, "default": _shown(value), **{k: f.metadata[k] for k in KEYS}})
    return out


def undocumented(cls: type) -> list[str]:
    """The fields of ``cls`` (and of its nested settings) without a unit or what they guard."""
    out = []
    for f in dataclasses.fields(cls):
        value = _value(f)
        if dataclasses.is_dataclass(value):
            out += [f"{f.name}.{n}" for n in undocumented(type(value))]
        elif not (f.metadata.get("unit") and f.metadata.get("guards")):
            out.append(f.name)
    return out


def documented(cls: type) -> type:
    """Class decorator: ``cls``'s docstring completed with an ``Attributes`` section made from its
    fields' metadata (numpydoc)."""
    lines = ["", "Attributes", "----------"]
    for f in dataclasses.fields(cls):
        value = _value(f)
        if dataclasses.is_dataclass(value):
            lines += [f"{f.name} : {type(value).__name__}", f"    {(type(value).__doc__ or '').splitlines()[0]}"]
            continue
        m = f.metadata
        lines.append(f"{f.name} : {type(value).__name__}, default {_shown(value)}")
        text = f"[{m['unit']}] {m['guards']}" + (f" Calibration: {m['calibration']}" if m["calibration"] else "")
        lines += textwrap.wrap(text, 100, initial_indent="    ", subsequent_indent="    ")
    cls.__doc__ = inspect.cleandoc(cls.__doc__ or "") + "\n" + "\n".join(lines) + "\n"
    return cls


def markdown_table(cls: type) -> str:
    """The documentation's table of ``cls``'s settings: name, default and unit, what it guards, how it
    was calibrated."""

    def cell(text: str) -> str:
        return text.replace("|", "\\|") or "none recorded"

    out = ["| setting | default | unit | what it guards | how it was calibrated |", "|---|---|---|---|---|"]
    out += [
        f"| `{r['name']}` | {cell(r['default'])} | {cell(r['unit'])} | {cell(r['guards'])} | {cell(r['calibration'])} |"
        for r in rows(cls)
    ]
    return "\n".join(out) + "\n"
