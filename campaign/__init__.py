"""Flight-test campaign: matrix, status points, the flying engine, logs and CLI."""
