"""Many realisations, or a grid of scenes, on ``dask.distributed``: ``scenesim batch``.

Design (DESIGN.md section 9, "Batches"):

* :mod:`scenesim.batch.plan`: a scene file (N realisations) or a batch file (grids
  over scene keys, the detectors of one exposure) validated into tasks; each
  realisation's seed spawned from one batch seed, so nothing depends on workers,
  order or retries;
* :mod:`scenesim.batch.tasks`: one realisation on a worker (simulate, fit, grade),
  written atomically where it runs, returning a record of a few kB;
* :mod:`scenesim.batch.manifest`: the manifest (one row per task), the per-task
  records that make a batch resumable, and the lock;
* :mod:`scenesim.batch.runner`: dask's ``LocalCluster`` or any scheduler, retries,
  interrupts;
* :mod:`scenesim.batch.pool`: the comparisons pooled over realisations, with
  standard errors across realisations;
* :mod:`scenesim.batch.command`: the ``scenesim batch`` and ``compare --pool``
  commands; :mod:`scenesim.batch.bench`: ``scenesim bench batch``.

dask is an optional dependency (``pip install 'scenesim[batch]'``): this package
imports without it, and says how to install it when a batch runs.
"""

from noise.lazy import lazy_exports

#: Public name -> the module that defines it (imported on first use: the command
#: line imports :mod:`scenesim.batch.options` without the batch machinery).
_EXPORTS = {
    "FITTERS": "scenesim.batch.plan",
    "BatchPlan": "scenesim.batch.plan",
    "Point": "scenesim.batch.plan",
    "Task": "scenesim.batch.plan",
    "plan_batch": "scenesim.batch.plan",
    "realisation_seed": "scenesim.batch.plan",
    "spawn_key": "scenesim.batch.plan",
    "run_batch": "scenesim.batch.runner",
    "BatchResult": "scenesim.batch.runner",
    "BatchError": "scenesim.batch.runner",
    "run_task": "scenesim.batch.tasks",
    "pool_reports": "scenesim.batch.pool",
    "format_pooled": "scenesim.batch.pool",
    "pool_directory": "scenesim.batch.pool",
}

__all__ = list(_EXPORTS)


__getattr__, __dir__ = lazy_exports('scenesim.batch', _EXPORTS, globals())
