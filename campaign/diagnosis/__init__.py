"""``campaign diagnose`` end to end: reads the data, runs :func:`diagnose.diagnosis.diagnose`, flies
the held-out replays on the model and its extension, refines and bands the extension, writes the files."""
