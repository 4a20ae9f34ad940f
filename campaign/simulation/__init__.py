"""Flying: test matrices and status points, the aircraft folder and effect overlays, the property
catalog, the engine that trims, flies and logs, the instrument model and Dryden turbulence."""
