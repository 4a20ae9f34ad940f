"""What a JSBSim model gets wrong, from measured logs: residuals -> candidate causes -> verdict ->
extension -> gain. :func:`diagnose.diagnosis.diagnose` runs the stages in order; ``campaign
diagnose`` adds the held-out replays and the files. The diagnosis reads logs and evaluates the
model under test; it never flies, and never reads an effect overlay or an instrument profile."""
