"""Identification from campaign logs (paper eqs. 1-9). Reads logs only.

This package never imports ``campaign``'s flying code and never reads effect
overlays: it sees only what flight-test instrumentation records.
"""
