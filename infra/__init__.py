"""Infrastructure every job uses and no science lives in: the warm process pool and its Dask
counterpart (:mod:`infra.pool`), and reading, checking and loading JSBSim models (:mod:`infra.model`).
Imports none of the project's other packages."""
