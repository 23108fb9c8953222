"""``scenesim bench batch``: exposures per minute on dask against a loop of runs.

One case, ``n`` realisations of ``scenes/quick.toml`` (256x256, RAPID x 10, full
noise, five stars; each realisation simulated, written, GLS-fitted and compared with
its truth, as the scene asks), timed four ways in the same process:

* ``loop``: a plain Python loop of :func:`scenesim.run.run_scene` calls with the
  realisations' seeds, default threads (what a user's shell loop of ``scenesim run
  --seed`` does, without the interpreter start-ups): the baseline;
* ``loop, 1 thread``: the same with one thread per run, the setting of the batch's
  tasks below, so the difference is the batch's own cost;
* ``batch, 1 worker`` and ``batch, 2 workers``: :func:`scenesim.batch.runner.run_batch`
  on a new ``LocalCluster`` (one thread per task), wall time of the whole call:
  cluster start, worker warm-up (imports), tasks, manifest, stop; and, apart, the
  wall time of its tasks alone (first submitted to last finished,
  ``BatchResult.task_seconds``): the steady throughput that a long batch tends to,
  beside the fixed start-up and stop cost that a short one pays.

* ``2 processes``: no dask, two plain processes (``multiprocessing``, spawned),
  each a loop of :func:`~scenesim.run.run_scene` on one thread over half the
  realisations, timed from a barrier after each has made one warm-up run (imports
  and first calls) to the last one finished: what this machine gives two
  processes at all (memory and cache shared, the hypervisor's cores), the ceiling
  a 2-worker batch can reach.

The five are timed in two passes, the second in reverse order (loop, loop 1 thread,
1 worker, 2 workers, 2 processes; then 2 processes, ..., loop), so that a load that drifts during
the run (a shared machine) weighs on each about equally; each throughput is the
``2 n`` exposures over the two passes' wall time, and each pass's own figure is
printed beside it, with the CPU seconds per exposure of each way (this process and
its reaped children: on a loaded machine the CPU a batch's overhead costs shows
there when the wall times only show the contention).  Then the scheduler's own cost: the start and stop of a 1-worker
``LocalCluster``, and 200 no-op tasks submitted at once and gathered (wall time per
task: the round trip through the scheduler and a worker, serialisation included).
Every number is measured in the run that prints it.
"""

import os
import resource
import tempfile
import time

import numpy as np

from noise.fast.memory import keep_freed_memory
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
                      dashboard_address=":0") as cluster, \
            Client(cluster, set_as_default=False) as client:
        client.submit(_noop, -1, pure=False).result()          # warm
        t1 = time.perf_counter()
        futures = client.map(_noop, range(_NOOP_TASKS), pure=False)
        client.gather(futures)
        per_task = (time.perf_counter() - t1) / _NOOP_TASKS
        del futures
        t2 = time.perf_counter()
    return (t1 - t0) + (time.perf_counter() - t2), per_task


#: The four ways, in the order of the first pass (the second runs them reversed).
_WAYS = ("loop", "loop_1thread", "batch_1", "batch_2", "procs_2")


def _process_loop(tasks, folder, barrier, queue):
    """One of the ``2 processes``: a warm-up run, the barrier, then ``tasks`` in a
    loop of runs on one thread; puts the loop's wall seconds on ``queue``."""
    try:
        keep_freed_memory()           # the malloc policy of the scenesim command
        scene = load_scene(QUICK_SCENE)
        opts = EngineOptions(threads=1)
        warm = os.path.join(folder, f"warm{os.getpid()}.fits")
        run_scene(scene, output=warm, seed=tasks[0].seed, options=opts, progress=False)
        barrier.wait()
        t0 = time.perf_counter()
        for t in tasks:
            run_scene(scene, output=os.path.join(folder, f"{t.name}.fits"),
                      seed=t.seed, options=opts, progress=False)
        queue.put(time.perf_counter() - t0)
    except BaseException as exc:                   # noqa: BLE001 - to the parent
        barrier.abort()
        queue.put(f"{type(exc).__name__}: {exc}")


def _time_processes(tasks, folder, nproc=2):
    """Wall seconds of ``nproc`` plain processes sharing ``tasks`` (see
    :func:`_process_loop`): the slowest one's loop."""
    import multiprocessing
    ctx = multiprocessing.get_context("spawn")
    barrier, queue = ctx.Barrier(nproc), ctx.Queue()
    procs = [ctx.Process(target=_process_loop,
                         args=(tasks[i::nproc], folder, barrier, queue))
             for i in range(nproc)]
    for pr in procs:
        pr.start()
    try:
        got = [queue.get(timeout=600) for _ in procs]
    finally:
        for pr in procs:
            pr.join(timeout=60)
            if pr.is_alive():
                pr.kill()
    bad = [g for g in got if isinstance(g, str)]
    if bad:
        raise RuntimeError(f"a bench process failed: {bad[0]}")
    return max(got)
_PASSES = 2


def _time_way(way, tasks, scene, n, threads, folder):
    """``(wall s, CPU s, task wall s)`` of the ``n`` realisations done one ``way``
    into ``folder`` (task wall: a batch's tasks alone, without its start-up and
    stop; a loop's whole wall)."""
    os.makedirs(folder)
    t0, c0 = time.perf_counter(), _cpu_seconds()
    if way.startswith("procs"):
        task_wall = _time_processes(tasks, folder, int(way.split("_")[1]))
    elif way.startswith("loop"):
        opts = EngineOptions(threads=threads if way == "loop" else 1)
        for t in tasks:
            run_scene(scene, output=os.path.join(folder, f"{t.name}.fits"),
                      seed=t.seed, options=opts, progress=False)
        task_wall = None
    else:
        workers = int(way.split("_")[1])
        plan = plan_batch(QUICK_SCENE, out=os.path.join(folder, "out"), realisations=n)
        res = run_batch(plan, workers=workers, threads=1, progress=False)
        if len(res.ran) != n:
            raise RuntimeError(f"batch ran {len(res.ran)} of {n} tasks")
        task_wall = res.task_seconds
    wall = time.perf_counter() - t0
    return wall, _cpu_seconds() - c0, (wall if task_wall is None else task_wall)


def bench_batch(n, threads):
    """``n`` realisations of quick.toml, twice: a loop of runs against dask with 1
    and 2 workers, plus the scheduler's overhead per task (see the module notes).

    ``threads`` is the loop's default thread count (the batch tasks run one each).
    """
    # imported here: scenesim.bench imports this module for its WORKLOADS
    from scenesim.bench.floor import floor_counts, typical_lambda
    plan_probe = plan_batch(QUICK_SCENE, out=os.path.join(tempfile.gettempdir(), "x"),
                            realisations=n)
    tasks = plan_probe.tasks()
    scene = load_scene(QUICK_SCENE)          # its [output]: GLS fit and compare
    walls = {w: [] for w in _WAYS}
    cpus = {w: [] for w in _WAYS}
    steady = {w: [] for w in _WAYS}
    with tempfile.TemporaryDirectory() as tmp:
        for p in range(_PASSES):
            for way in (_WAYS if p % 2 == 0 else _WAYS[::-1]):
                wall, cpu, task_wall = _time_way(way, tasks, scene, n, threads,
                                                 os.path.join(tmp, f"{way}_{p}"))
                walls[way].append(wall)
                cpus[way].append(cpu)
                steady[way].append(task_wall)
    start_stop, per_task = _scheduler_overhead()
    total = {w: sum(v) for w, v in walls.items()}
    count = _PASSES * n
    per_min = {w: 60.0 * count / total[w] for w in _WAYS}
    steady_total = {w: sum(v) for w, v in steady.items()}
    steady_min = {w: 60.0 * count / steady_total[w] for w in _WAYS}
    fixed = {w: (total[w] - steady_total[w]) / _PASSES for w in _WAYS}

    cpu_per = {w: sum(cpus[w]) / count for w in _WAYS}

    def rate(way):
        passes = "/".join(f"{60.0 * n / v:.1f}" for v in walls[way])
        return f"{per_min[way]:.1f} ({passes})"

    engine, _ = build_engine(tasks[0].scene)
    det, ro = engine.detector, engine.readout
    n_reads = ro.nints * len(ro.needed_reads)
    charged = int(np.count_nonzero(engine.rate[~det.reference_mask()] > 0))
    nn, npo = floor_counts(det, scene.noise, n_reads, ro.nints, charged, n_reads)
    detail = (
        f"quick.toml x {n}, {_PASSES} passes (the second in reverse order) (256x256, "
        f"RAPID x 10, simulate + GLS fit + compare each); exposures/min over both "
        f"passes (pass 1/pass 2): loop of run_scene {rate('loop')} ({threads} "
        f"threads, the baseline), {rate('loop_1thread')} (1 thread); dask "
        f"LocalCluster, 1 thread per task: 1 worker {rate('batch_1')}, 2 workers "
        f"{rate('batch_2')}; 2 workers = {total['batch_1'] / total['batch_2']:.2f}x "
        f"1 worker, {total['loop'] / total['batch_2']:.2f}x the loop; 1 worker = "
        f"{total['loop_1thread'] / total['batch_1']:.2f}x the 1-thread loop (batch "
        f"minus 1-thread loop per exposure "
        f"{(total['batch_1'] - total['loop_1thread']) / count:+.3f} s); CPU s per "
        f"exposure (this process and its reaped children, i.e. the workers): loop "
        f"{cpu_per['loop']:.2f}, 1-thread loop {cpu_per['loop_1thread']:.2f}, 1 worker "
        f"{cpu_per['batch_1']:.2f}, 2 workers {cpu_per['batch_2']:.2f}, 2 processes "
        f"{cpu_per['procs_2']:.2f} (their warm-up runs and imports included); "
        f"scheduler: "
        f"{1e3 * per_task:.2f} ms per task ({_NOOP_TASKS} no-op tasks), cluster start "
        f"+ stop {start_stop:.2f} s; two plain processes (no dask, after a warm-up run "
        f"each) {steady_min['procs_2']:.1f} exposures/min = "
        f"{total['loop_1thread'] / steady_total['procs_2']:.2f}x the 1-thread loop "
        f"(this machine's own 2-process scaling, the ceiling of 2 workers); steady throughput (the batch's tasks alone, "
        f"first submitted to last finished, without its start-up, worker warm-up and "
        f"stop: {fixed['batch_1']:.2f} s per call with 1 worker, "
        f"{fixed['batch_2']:.2f} s with 2): 1 worker {steady_min['batch_1']:.1f}, "
        f"2 workers {steady_min['batch_2']:.1f} exposures/min, 2 workers = "
        f"{steady_total['batch_1'] / steady_total['batch_2']:.2f}x 1 worker, 1 worker "
        f"= {total['loop_1thread'] / steady_total['batch_1']:.2f}x the 1-thread loop, "
        f"2 workers = {steady_total['procs_2'] / steady_total['batch_2']:.2f}x the "
        f"two plain processes; "
        f"wall/floor columns: the 2-worker batch, both "
        f"passes (CPU: driver and its worker processes) against the random numbers of "
        f"its {count} exposures")
    return dict(wall=total["batch_2"], cpu=sum(cpus["batch_2"]), n_normal=count * nn,
                n_poisson=count * npo, lam=typical_lambda(engine.rate, det.frame_time),
                detail=detail, walls=walls, cpus=cpus, cpu_per_exposure=cpu_per,
                exposures_per_minute=per_min,
                steady_exposures_per_minute=steady_min,
                fixed_seconds_per_call=fixed,
                scheduler_seconds_per_task=per_task,
                cluster_start_stop_seconds=start_stop,
                pixel_reads=int(count * det.ny * det.nx * n_reads))
