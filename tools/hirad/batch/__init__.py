"""Batch studies: one base config, many variants, each a bake of its own (`hirad batch`).

- `study`: the study file (base config, `set`, `variants`, `matrix`, the cluster), its jobs,
  each validated by the config schema before anything runs.
- `index`: the study's SQLite index (one row per job: key, status, attempts, timings, exit
  status, error, output), updated in transactions.
- `runner`: the jobs on Dask distributed (a LocalCluster, an existing scheduler, or a
  dask-jobqueue cluster), each bake a separate `python -m hirad.cli bake` process.
- `summary`: the study's CSV and HTML comparison of the variants' headline numbers.
"""

from .study import Job, Study, StudyFileError, load_study

__all__ = ["Job", "Study", "StudyFileError", "load_study"]
