"""The package's plumbing: atomic outputs, the stage timer and manifest, Ctrl-C between chunks,
independent tasks here or on Dask, threads, numba's cache and the kernels' precompilation. Not
API: docs/architecture.md shows where each sits."""
