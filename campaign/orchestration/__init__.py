"""Running many flights: the campaign runner (local workers, resume), the Dask cluster, the results
store (atomic writes, manifest)."""
