"""Flight-test campaigns, one sub-package per job.

- :mod:`campaign.simulation`: the matrix and status points, the aircraft and its overlays, the engine
  that trims, flies and logs, the instruments and turbulence;
- :mod:`campaign.orchestration`: running a matrix on local workers or a Dask cluster, the results store;
- :mod:`campaign.importing`: measured data from elsewhere into the log schema;
- :mod:`campaign.modelling`: a whole JSBSim aircraft from an identification, and its trim;
- :mod:`campaign.replays`: the takeoff and landing cases flown on each model, Part 60 metrics and plots;
- :mod:`campaign.diagnosis`: the diagnosis run end to end (held-out replays, refinement, bands, files);
- :mod:`campaign.design`: the next flight that separates rival causes;
- :mod:`campaign.reports`: the HTML report;
- :mod:`campaign.validation`: generated hidden effects and small matrices, for the tests and benchmarks;
- :mod:`campaign.cli`: the ``campaign`` command.
"""
