"""The ``campaign`` command."""

from campaign.cli.main import main

__all__ = ["main"]
