"""The aircraft this tool ships: ``737/`` is the 737-800 JSBSim model flown by default, with its
engines and the effect overlay that makes it the reference aeroplane (data, never code)."""

from pathlib import Path

#: The shipped 737-800 folder (``737/737.xml``, ``Engines/``, ``effects/reference.xml``).
SHIPPED_737 = Path(__file__).resolve().parent / "737"
