"""The HTML report of a campaign and of a diagnosis."""
