"""``scenesim bench batch``: exposures per minute on dask against a loop of runs.

One case, ``n`` realisations of ``scenes/quick.toml`` (256x256, RAPID x 10, full
noise, five stars; each realisation simulated, written, GLS-fitted and compared with
its truth, as the scene asks), timed four ways in the same process, back to back:

* ``loop``: a plain Python loop of :func:`scenesim.run.run_scene` calls with the
  realisations' seeds, default threads (what a user's shell loop of ``scenesim run
  --seed`` does, without the interpreter start-ups);
* ``loop, 1 thread``: the same with one thread per run, the setting of the batch's
  tasks below, so the difference is the batch's own cost;
* ``batch, 1 worker`` and ``batch, 2 workers``: :func:`scenesim.batch.runner.run_batch`
  on a new ``LocalCluster`` (one thread per task), wall time of the whole call:
  cluster start, worker imports, tasks, manifest, stop.

Then the scheduler's own cost: the start and stop of a 1-worker ``LocalCluster``,
and 200 no-op tasks submitted at once and gathered (wall time per task: the
round trip through the scheduler and a worker, serialisation included).
Every number is measured in the run that prints it.
"""

import os
import resource
import tempfile
import time

import numpy as np

from scenesim.batch.plan import plan_batch
from scenesim.batch.runner import run_batch
from scenesim.engine import EngineOptions
from scenesim.run import build_engine, run_scene
from scenesim.scene import load_scene

__all__ = ["bench_batch", "QUICK_SCENE"]

#: The scene of the workload.
QUICK_SCENE = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(
    os.path.abspath(__file__)))), "scenes", "quick.toml")

_NOOP_TASKS = 200


def _cpu_seconds():
    """CPU seconds of this process and its reaped children (the local cluster's
    worker processes, once it is closed)."""
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + kids.ru_utime + kids.ru_stime


def _noop(i):
    return i


def _scheduler_overhead():
    """``(cluster start + stop s, s per no-op task)`` on a 1-worker LocalCluster."""
    from dask.distributed import Client, LocalCluster
    t0 = time.perf_counter()
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, \
            Client(cluster, set_as_default=False) as client:
        client.submit(_noop, -1, pure=False).result()          # warm
        t1 = time.perf_counter()
        futures = client.map(_noop, range(_NOOP_TASKS), pure=False)
        client.gather(futures)
        per_task = (time.perf_counter() - t1) / _NOOP_TASKS
        del futures
        t2 = time.perf_counter()
    return (t1 - t0) + (time.perf_counter() - t2), per_task


def bench_batch(n, threads):
    """``n`` realisations of quick.toml: a loop of runs against dask with 1 and 2
    workers, plus the scheduler's overhead per task (see the module notes).

    ``threads`` is the loop's default thread count (the batch tasks run one each).
    """
    # imported here: scenesim.bench imports this module for its WORKLOADS
    from scenesim.bench.floor import floor_counts, typical_lambda
    plan_probe = plan_batch(QUICK_SCENE, out=os.path.join(tempfile.gettempdir(), "x"),
                            realisations=n)
    tasks = plan_probe.tasks()
    scene = load_scene(QUICK_SCENE)          # its [output]: GLS fit and compare
    wall = {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, opts in (("loop", EngineOptions(threads=threads)),
                            ("loop_1thread", EngineOptions(threads=1))):
            os.makedirs(os.path.join(tmp, label))
            t0 = time.perf_counter()
            for t in tasks:
                run_scene(scene, output=os.path.join(tmp, label, f"{t.name}.fits"),
                          seed=t.seed, options=opts, progress=False)
            wall[label] = time.perf_counter() - t0
        for workers in (1, 2):
            plan = plan_batch(QUICK_SCENE, out=os.path.join(tmp, f"w{workers}"),
                              realisations=n)
            t0, c0 = time.perf_counter(), _cpu_seconds()
            res = run_batch(plan, workers=workers, threads=1, progress=False)
            wall[f"batch_{workers}"] = time.perf_counter() - t0
            cpu = _cpu_seconds() - c0
            if len(res.ran) != n:
                raise RuntimeError(f"batch ran {len(res.ran)} of {n} tasks")
    start_stop, per_task = _scheduler_overhead()
    per_min = {k: 60.0 * n / v for k, v in wall.items()}
    engine, _ = build_engine(tasks[0].scene)
    det, ro = engine.detector, engine.readout
    n_reads = ro.nints * len(ro.needed_reads)
    charged = int(np.count_nonzero(engine.rate[~det.reference_mask()] > 0))
    nn, npo = floor_counts(det, scene.noise, n_reads, ro.nints, charged, n_reads)
    detail = (
        f"quick.toml x {n} (256x256, RAPID x 10, simulate + GLS fit + compare each); "
        f"exposures/min: loop of run_scene {per_min['loop']:.1f} ({threads} threads), "
        f"{per_min['loop_1thread']:.1f} (1 thread); dask LocalCluster, 1 thread per "
        f"task: 1 worker {per_min['batch_1']:.1f}, 2 workers {per_min['batch_2']:.1f} "
        f"({wall['batch_1'] / wall['batch_2']:.2f}x 1 worker, "
        f"{wall['loop'] / wall['batch_2']:.2f}x the loop); batch minus 1-thread loop "
        f"per exposure {(wall['batch_1'] - wall['loop_1thread']) / n:+.3f} s; "
        f"scheduler: {1e3 * per_task:.2f} ms per task ({_NOOP_TASKS} no-op tasks), "
        f"cluster start + stop {start_stop:.2f} s; wall/floor columns: the 2-worker "
        f"batch (CPU: driver and its worker processes) against the random numbers of "
        f"its {n} exposures")
    return dict(wall=wall["batch_2"], cpu=cpu, n_normal=n * nn,
                n_poisson=n * npo, lam=typical_lambda(engine.rate, det.frame_time),
                detail=detail, walls=wall, exposures_per_minute=per_min,
                scheduler_seconds_per_task=per_task,
                cluster_start_stop_seconds=start_stop,
                pixel_reads=int(n * det.ny * det.nx * n_reads))
