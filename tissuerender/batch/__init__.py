"""Batches: many sequences from one base scene plus randomisation (``tissuerender batch SPEC.toml -o DIR``).

``spec`` reads and validates the spec file (docs/batch-format.md); ``resolve`` turns sequence ``i`` of a spec
into a fully resolved scene (randomised from the spec seed and ``i`` only); ``run`` renders the sequences,
serially or as Dask tasks, and keeps the batch manifest ``batch.json``.
"""
from tissuerender.batch.run import run_batch
from tissuerender.batch.spec import BatchSpec, load_spec

__all__ = ["BatchSpec", "load_spec", "run_batch"]
