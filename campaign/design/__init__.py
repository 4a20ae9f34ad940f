"""Test design: ``campaign plan``, the next flight that separates the rival readings of a diagnosis."""
