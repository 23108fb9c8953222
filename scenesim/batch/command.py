"""``scenesim batch`` and ``scenesim compare --pool``: the command-line side.

``scenesim batch SCENE_OR_BATCH --out DIR`` plans the batch
(:func:`scenesim.batch.plan.plan_batch`), runs it (:func:`scenesim.batch.runner.run_batch`)
and prints what ran and, with ``--compare``, the pooled tables
(:func:`scenesim.batch.pool.format_pooled`); ``scenesim compare --pool DIR`` prints
the pooled tables of a batch directory again.
"""

import os
import sys

from noise.errors import ParameterError
from scenesim.batch.plan import plan_batch
from scenesim.batch.pool import format_pooled, pool_directory
from scenesim.batch.runner import BatchError, run_batch

__all__ = ["batch_command", "pool_command", "format_tables"]

#: run_batch's arguments that are options of the command by the same name.
_OPTIONS = ("connect_timeout", "workers", "threads", "retries", "scheduler")


def format_tables(pooled, *, source="", points=()):
    """All pooled tables of a batch, one per grid point and fitter.

    ``points`` is the manifest's list of grid points (``label`` and ``params``), so
    that each table names the scene keys of its point."""
    keys = {p["label"]: ", ".join(f"{k} = {v}" for k, v in p["params"])
            for p in points}
    blocks = []
    for label, per in pooled.items():
        for fitter, table in per.items():
            where = f"{os.path.basename(source)} " if source else ""
            point = (f"grid point {label}" + (f" ({keys[label]})" if keys.get(label)
                                              else "") + ", ") if label else ""
            blocks.append(format_pooled(table, title=f"Pooled: {where}{point}fitter "
                                                      f"{fitter}"))
    return "\n\n".join(blocks)


def _say(text=""):
    """Print ``text``; once the reader of a pipe is gone (``| head``), print nothing
    more instead of failing: the batch itself goes on and ends normally."""
    try:
        print(text, flush=True)
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())       # and the flush at exit is silent
        os.close(devnull)


def _fitters(values):
    if values is None:
        return None
    return [f.strip() for v in values for f in v.split(",") if f.strip()]


def batch_command(args):
    """``scenesim batch``: run a batch; print its summary and pooled tables."""
    plan = plan_batch(args.scene, out=args.out, realisations=args.realisations,
                      seed=args.seed, fit=_fitters(args.fit), compare=args.compare,
                      ramp=args.ramp, refpix=args.refpix)

    def log(line):
        if not args.quiet:
            _say(line)

    from scenesim.budget import one_line_warnings
    try:
        with one_line_warnings("scenesim batch"):    # the tasks' warnings, each once
            res = run_batch(plan, scheduler=args.scheduler, workers=args.workers,
                            threads=args.threads, retries=args.retries,
                            connect_timeout=args.connect_timeout,
                            progress=not args.quiet and sys.stderr.isatty(), log=log,
                            force=args.force)
    except ParameterError as exc:                  # by the options' names
        text = str(exc)
        for name in _OPTIONS:
            text = text.replace(f"'{name}'", f"'--{name.replace('_', '-')}'")
        raise type(exc)(text) from exc
    except BatchError as exc:                      # the finished tasks' tables first
        if exc.pooled and not args.quiet:
            _say(format_tables(exc.pooled, source=plan.source,
                               points=exc.manifest.get("points", ())))
            _say()
        raise
    n = len(res.ran)
    rate = (f" ({60 * n / res.seconds:.1f} exposures/min; the tasks alone "
            f"{60 * n / res.task_seconds:.1f}/min after {res.startup_seconds:.1f} s "
            f"of start-up)") if n and res.task_seconds > 0 else ""
    log(f"batch: {n} run, {len(res.skipped)} already finished, {len(res.failed)} "
        f"failed, in {res.seconds:.1f} s{rate}; batch seed {res.plan.batch_seed} "
        f"({res.plan.seed_source}); manifest {os.path.join(args.out, 'batch.json')}")
    if res.pooled and not args.quiet:
        _say()
        _say(format_tables(res.pooled, source=plan.source,
                           points=res.manifest.get("points", ())))
    return 0


def pool_command(args):
    """``scenesim compare --pool DIR``: the pooled tables of a batch directory."""
    manifest, pooled = pool_directory(args.pool)
    _say(format_tables(pooled, source=manifest.get("source", ""),
                       points=manifest.get("points", ())))
    return 0
