"""Running a batch on ``dask.distributed``: a local cluster, or any scheduler.

The engine is dask's (an optional dependency, ``pip install 'scenesim[batch]'``,
imported only here, when a batch runs): by default a ``LocalCluster`` of worker
processes on this machine, one task at a time per worker, as many workers as cores,
each task's engine and fits running ``cores // workers`` threads; with
``scheduler='tcp://HOST:8786'`` (or the path of a scheduler file written by
``dask scheduler --scheduler-file``, dask-jobqueue, dask-kubernetes, ...) the same
tasks go to that cluster, whose workers must see the output directory (a shared
file system).  No scheduler of our own.

Order of a batch (:func:`run_batch`), so that every input error is one message
before any task starts and nothing is written:

1. the scheduler option's syntax, the output directory's parent, the manifest
   already in the directory (another batch's is refused), dask installed;
2. connect to the scheduler, or start the local cluster (an address nobody answers
   is refused after ``connect_timeout`` seconds);
3. create the directory, take its lock, remove the temporary files of dead
   processes, find the finished tasks (:func:`scenesim.batch.manifest.load_record`),
   write the manifest;
4. run :func:`scenesim.batch.tasks.warm_worker` on every worker (the imports a
   task would make on first use, done once per worker, in parallel, before any
   task: reported as part of the start-up, not of the throughput), then submit
   the rest (``retries``: a task that raises is run again; a task whose
   worker dies is rescheduled by dask itself, up to its
   ``distributed.scheduler.allowed-failures``), and as each finishes record it and
   rewrite the manifest (at most once a second);
5. close the cluster, remove the temporary files killed workers left, write the
   manifest, pool the comparisons (:mod:`scenesim.batch.pool`).

Ctrl-C (or SIGTERM/SIGHUP, which the ``scenesim`` command turns into the same
exception) cancels the tasks, stops the local cluster, removes the temporary files,
writes the manifest of what finished and re-raises: re-running the same command
completes the rest.  Only task descriptions (a scene and a seed) and records (a few
kB) pass through the scheduler.
"""

import collections
import contextlib
import dataclasses
import importlib.util
import logging
import os
import re
import secrets
import signal
import threading
import time
import warnings
from dataclasses import dataclass

from noise.errors import ParameterError, ScenesimError, ScenesimWarning
from noise.fitsio import TEMP_PATTERN, output_error, remove_stale_temps
from scenesim.budget import check_batch_budget
from scenesim.batch.manifest import (Manifest, batch_lock, check_same_batch,
                                     load_record, read_manifest)
from scenesim.batch.pool import pool_reports
from scenesim.batch.tasks import run_task, warm_worker
from scenesim.outputs import check_not_dangling, scene_inputs

__all__ = ["run_batch", "BatchResult", "BatchError", "check_scheduler"]

_ADDRESS = re.compile(r"^(?:(tcp|tls|ucx|ws|wss)://)?\[?[A-Za-z0-9_.:-]*\]?:\d{1,5}/?$")


#: The longest wait for a scheduler, seconds (``connect_timeout``).
MAX_CONNECT_TIMEOUT = 86400.0


class BatchError(ScenesimError, RuntimeError):
    """Tasks of a batch failed (after their retries); re-running retries them.

    ``pooled`` and ``manifest`` hold the pooled comparison of the finished tasks
    and the manifest (as :class:`BatchResult`'s), for the caller to show."""

    def __init__(self, message, *, pooled=None, manifest=None):
        super().__init__(message)
        self.pooled = pooled or {}
        self.manifest = manifest or {}


@dataclass
class BatchResult:
    """What a batch did.

    Attributes
    ----------
    plan : scenesim.batch.plan.BatchPlan
    manifest : dict
        The manifest as written.
    ran, skipped, failed : list of str
        Task names run now, found finished, failed.
    pooled : dict
        ``{point label or '': {fitter: pool_reports(...)}}`` (empty without compare).
    seconds : float
        Wall time of the whole call (cluster start and stop included).
    task_seconds : float
        Wall time from the first task submitted to the last one finished (0 when
        nothing ran): ``len(ran) / task_seconds`` is the batch's throughput.
    startup_seconds : float
        Wall time before the first task was submitted: checks, cluster start or
        connection, worker warm-up (:func:`scenesim.batch.tasks.warm_worker`),
        manifest.
    dashboard : str or None
        dask's dashboard link, when it serves one.
    workers : int
        Workers of the cluster when the tasks were submitted.
    """

    plan: object
    manifest: dict
    ran: list
    skipped: list
    failed: list
    pooled: dict
    seconds: float
    dashboard: str | None
    workers: int
    task_seconds: float = 0.0
    startup_seconds: float = 0.0


def check_scheduler(scheduler):
    """``None``, ``('address', addr)`` or ``('file', path)`` for the scheduler option.

    An address is ``[tcp|tls|ucx|ws|wss://]HOST:PORT``; anything else must be an
    existing scheduler file (JSON with an ``address``).
    """
    if scheduler is None:
        return None
    if not isinstance(scheduler, str) or not scheduler:
        raise ParameterError(f"'scheduler' must be an address (tcp://HOST:PORT) or a "
                             f"scheduler file, got {scheduler!r}")
    if "://" in scheduler or _ADDRESS.match(scheduler):
        if not _ADDRESS.match(scheduler):
            raise ParameterError(
                f"'scheduler' {scheduler!r} is not a dask scheduler address; expected "
                f"tcp://HOST:PORT (or tls://, ucx://, ws://), e.g. tcp://10.0.0.5:8786")
        port = int(scheduler.rstrip("/").rsplit(":", 1)[1])
        if not 0 < port < 65536:
            raise ParameterError(f"'scheduler' {scheduler!r}: port {port} is not in "
                                 f"1..65535")
        return ("address", scheduler)
    if not os.path.isfile(scheduler):
        raise ParameterError(
            f"'scheduler' {scheduler!r} is neither an address (tcp://HOST:PORT) nor an "
            f"existing scheduler file")
    import json
    try:
        with open(scheduler, encoding="utf-8") as fh:
            address = json.load(fh)["address"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ParameterError(f"'scheduler' file {scheduler!r} is not a dask scheduler "
                             f"file (JSON with an 'address'): {exc}") from exc
    if not isinstance(address, str):
        raise ParameterError(f"'scheduler' file {scheduler!r}: 'address' is {address!r}")
    return ("file", os.path.abspath(scheduler))


def _import_dask():
    """``(Client, LocalCluster, as_completed)``, or a ParameterError saying how to
    install dask."""
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError as exc:
        raise ParameterError(
            f"scenesim batch runs on dask.distributed, which is not installed: pip "
            f"install 'scenesim[batch]' ({exc})") from exc
    return Client, LocalCluster, as_completed


def _check_out_writable(out_dir):
    """Raise before any work unless ``out_dir`` (or, where it does not exist yet, the
    directory that would hold it) can be written: a read-only one (file system or
    mode) gives one line, not an OSError once the workers are up."""
    check_not_dangling("out", out_dir)
    path = os.path.abspath(out_dir)
    while not os.path.exists(path):
        parent = os.path.dirname(path)
        if parent == path:
            break
        path = parent
    if not os.path.isdir(path):
        raise ParameterError(f"'out' {out_dir!r}: {path!r} is not a directory")
    if not os.access(path, os.W_OK | os.X_OK):
        raise ParameterError(f"'out' {out_dir!r}: the directory {path!r} is not "
                             f"writable")


def _failed_message(failed, ntasks, first_error, manifest_path):
    """What a batch whose tasks ``failed`` (names, of ``ntasks``) says at its end."""
    rest = ntasks - len(failed)
    others = ("" if rest == 0 else "; the other task is finished" if rest == 1
              else f"; the other {rest} are finished")
    return (f"{len(failed)} of {ntasks} tasks failed (first: {failed[0]}: "
            f"{first_error}){others}. Errors are in {manifest_path}; run the same "
            f"command again to retry them")


@contextlib.contextmanager
def _client(target, workers, connect_timeout, log):
    """A dask Client on the scheduler ``target``, or on a new LocalCluster."""
    Client, LocalCluster, _ = _import_dask()
    logging.getLogger("distributed").setLevel(logging.ERROR)
    cluster = client = None
    # dask's nanny sets its pre-spawn variables (OMP_NUM_THREADS=1,
    # MALLOC_TRIM_THRESHOLD_=65536, ...) in this process's environment to pass them
    # to the workers, and leaves them there: put the caller's environment back
    environ = dict(os.environ)
    try:
        if target is None:
            with _sigint_blocked():
                # the scheduler serves HTTP with or without bokeh; dashboard_address
                # None is its default port 8787, where a second batch (or any other
                # cluster) printed distributed's "port 8787 is already in use" even
                # with -q: a free port, always
                cluster = LocalCluster(n_workers=workers, threads_per_worker=1,
                                       processes=True, dashboard_address=":0",
                                       # a worker whose scheduler stops first (Ctrl-C)
                                       # logs its failed heartbeat at ERROR; task errors
                                       # reach the manifest through their futures
                                       silence_logs=logging.CRITICAL)
                client = Client(cluster, set_as_default=False)
        else:
            kind, where = target
            try:
                client = Client(**({"address": where} if kind == "address" else
                                   {"scheduler_file": where}),
                                timeout=connect_timeout, set_as_default=False)
            except (OSError, TimeoutError, ValueError) as exc:
                text = " ".join(str(exc).split())[:200] or type(exc).__name__
                raise ParameterError(
                    f"'scheduler' {where!r}: no dask scheduler answered within "
                    f"{connect_timeout:g} s ({text}); check the address, or omit "
                    f"--scheduler to run on a local cluster") from exc
        yield client, cluster
    finally:
        if client is not None:
            with contextlib.suppress(Exception):
                client.close(timeout=10)
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close(timeout=10)
        if os.environ != environ:
            os.environ.clear()
            os.environ.update(environ)


@contextlib.contextmanager
def _sigint_blocked():
    """SIGINT blocked in this thread while the local cluster starts.

    Ctrl-C goes to the terminal's whole process group, the local cluster's worker
    processes included; each would print its own KeyboardInterrupt traceback.  The
    cluster's IO-loop thread, started here, inherits the blocked signal, and so do the
    threads that spawn the worker processes (now and when a dead worker is restarted)
    and, through fork and exec, the workers themselves: Ctrl-C reaches this process
    alone, which cancels the tasks and closes the cluster.  A SIGINT that arrives
    while the cluster starts is delivered here when the block is lifted.

    multiprocessing's resource tracker is started first: starting it unblocks SIGINT
    in the thread that starts it (``resource_tracker.ensure_running``), which would
    be the IO-loop thread.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    from multiprocessing import resource_tracker
    resource_tracker.ensure_running()
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _remove_temps(folders, *, all_ours):
    """Remove temporary files in ``folders``: of dead processes (by pid), or, with
    ``all_ours`` (no task of this batch can be running), every one of a batch
    file (``r0007...``, ``batch.json``).  Returns how many were removed."""
    removed = 0
    for folder in folders:
        removed += len(remove_stale_temps(folder))
        if not all_ours:
            continue
        with contextlib.suppress(OSError):
            for entry in os.scandir(folder):
                m = TEMP_PATTERN.fullmatch(entry.name)
                if m and re.match(r"(r\d{4}|batch\.json)", m.group(2)) and \
                        entry.is_file(follow_symlinks=False):
                    with contextlib.suppress(OSError):
                        os.unlink(entry.path)
                        removed += 1
    return removed


def _one_line(exc):
    text = " ".join(str(exc).split()) or type(exc).__name__
    return f"{type(exc).__name__}: {text}"[:400]


def _pool(plan, records):
    """``{label: {fitter: pooled}}`` of the records with comparisons."""
    pooled = {}
    for p in plan.points:
        recs = [r for r in records if r["point"] == p.index]
        per = {}
        for f in plan.fitters:
            reps = [r["reports"][f] for r in recs if f in r.get("reports", {})]
            if reps:
                per[f] = pool_reports(reps)
        if per:
            pooled[p.label] = per
    return pooled


def run_batch(plan, *, scheduler=None, workers=None, threads=None, retries=2,
              connect_timeout=10.0, progress=True, log=None, on_result=None,
              force=False):
    """Run the tasks of ``plan`` that are not finished, on dask; pool the results.

    Parameters
    ----------
    plan : scenesim.batch.plan.BatchPlan
    scheduler : str, optional
        ``tcp://HOST:PORT`` or a scheduler file; default a new ``LocalCluster``.
    workers : int, optional
        Local cluster only: worker processes (default the number of cores).
    threads : int, optional
        Threads of each task's engine and fits (default ``cores // workers`` on the
        local cluster, 1 on another).  Results do not depend on it.
    retries : int
        Times a task that raised is run again (>= 0).
    connect_timeout : float
        Seconds to wait for the scheduler (> 0).
    progress : bool
        A progress bar over tasks (tqdm, on stderr).
    log : callable, optional
        Called with each line of news (workers, dashboard link, tasks to run).
    on_result : callable, optional
        Called with ``(task, record)`` when a task finishes (in this process).
    force : bool
        Run even when the tasks left need more memory (local cluster: each worker
        may hold the largest task) or disk than this machine has
        (:func:`scenesim.budget.check_batch_budget`, checked before any cluster
        starts).

    A script that calls this with the default local cluster must guard its entry
    point with ``if __name__ == "__main__":``: the cluster's worker processes are
    started by ``multiprocessing``'s *spawn*, which imports the main module again.

    Returns
    -------
    BatchResult

    Raises
    ------
    noise.errors.ParameterError
        Bad option, unreachable scheduler, another batch's manifest in the output
        directory, another batch running there, dask missing; before any task runs.
    BatchError
        Some tasks failed after their retries (the others are finished and
        recorded; running the batch again retries the failed ones).
    """
    t0 = time.perf_counter()
    log = log or (lambda line: None)
    target = check_scheduler(scheduler)
    cores = os.cpu_count() or 1
    if workers is not None:
        if target is not None:
            raise ParameterError("'workers' sizes the local cluster; an existing "
                                 "scheduler has its own workers (omit --workers)")
        workers = _check_positive("workers", workers)
    if threads is not None:
        threads = _check_positive("threads", threads)
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ParameterError(f"'retries' must be an integer >= 0, got {retries!r}")
    # finite and at most a day: dask takes it as a timedelta (inf: a KeyError from
    # its unit parser; 1e300: an OverflowError from the clock)
    if not (isinstance(connect_timeout, (int, float))
            and not isinstance(connect_timeout, bool)
            and 0 < connect_timeout <= MAX_CONNECT_TIMEOUT):
        raise ParameterError(f"'connect_timeout' must be > 0 and <= "
                             f"{MAX_CONNECT_TIMEOUT:g} (s, one day), got "
                             f"{connect_timeout!r}")
    parent = os.path.dirname(plan.out_dir)
    if not os.path.isdir(parent):
        raise ParameterError(f"'out': the directory {parent!r} that would hold "
                             f"{plan.out_dir!r} does not exist")
    if os.path.exists(plan.out_dir) and not os.path.isdir(plan.out_dir):
        raise ParameterError(f"'out' {plan.out_dir!r} is a file; expected a directory")
    plan = _checked_against_manifest(plan)
    _import_dask()
    if target is None:
        workers = workers or cores
        threads = threads or max(1, cores // workers)
    else:
        threads = threads or 1
    tasks = plan.tasks(threads=threads)
    # read-only look first: a batch with nothing left to run starts no cluster
    todo = [t for t in tasks if not _finished(plan, load_record(t))] \
        if os.path.isdir(plan.out_dir) else tasks
    counts = collections.Counter(t.point for t in todo)
    first = {}
    for t in todo:
        first.setdefault(t.point, t.scene)
    check_batch_budget([(first[k], n) for k, n in counts.items()],
                       workers=workers if target is None else None,
                       fitters=plan.fitters, force=force)
    _check_out_writable(plan.out_dir)
    with contextlib.ExitStack() as stack:
        client = cluster = None
        if todo:
            client, cluster = stack.enter_context(
                _client(target, workers, connect_timeout, log))
        try:
            os.makedirs(plan.out_dir, exist_ok=True)
            for p in plan.points:
                if p.label:
                    os.makedirs(os.path.join(plan.out_dir, p.label), exist_ok=True)
        except OSError as exc:
            raise output_error(plan.out_dir, exc) from exc
        folders = sorted({os.path.dirname(t.path["record"]) for t in tasks}
                         | {plan.out_dir})
        stack.enter_context(batch_lock(plan.out_dir))
        plan = _checked_against_manifest(plan)    # under the lock, again
        manifest = Manifest(plan, tasks, read_manifest(plan.out_dir))
        _remove_temps(folders, all_ours=cluster is not None)
        todo, skipped, records = [], [], []
        for t in tasks:
            rec = load_record(t)
            if _finished(plan, rec):
                manifest.done(t.name, rec)
                skipped.append(t.name)
                records.append(rec)
            else:
                todo.append((t, rec is not None))
                manifest.pending(t.name)
        manifest.write()
        ran, failed, nworkers, dashboard = [], [], 0, None
        t_tasks = t_start = None
        if todo and client is not None:
            nworkers = len(client.scheduler_info().get("workers", {}))
            dashboard = _dashboard(client, cluster)
            where = "local cluster" if cluster is not None else f"scheduler {target[1]}"
            log(f"batch: {len(tasks)} tasks ({len(skipped)} finished, {len(todo)} to "
                f"run) on {where}: {nworkers} workers, {threads} thread(s) per task"
                + (f"; dashboard {dashboard}" if dashboard else ""))
            if nworkers == 0:
                log("batch: the scheduler has no workers yet; the tasks wait for them")
            else:
                _warm_workers(client, plan.fitters, log)
            interrupted = True
            t_start = time.perf_counter()
            try:
                _submit_and_collect(client, todo, manifest, records, ran, failed,
                                    retries, progress, len(tasks), len(skipped),
                                    on_result)
                t_tasks = time.perf_counter() - t_start
                interrupted = False
            finally:
                if cluster is not None:
                    with contextlib.suppress(Exception):
                        client.close(timeout=10)
                    with contextlib.suppress(Exception):
                        cluster.close(timeout=10)
                # every worker of a local cluster is gone; on another cluster, after
                # a complete run every task's last attempt has finished
                _remove_temps(folders, all_ours=cluster is not None or not interrupted)
                if interrupted:
                    # tasks that finished on their workers after the interrupt
                    seen = set(ran) | set(failed)
                    for t, _ in todo:
                        rec = None if t.name in seen else load_record(t)
                        if _finished(plan, rec):
                            manifest.done(t.name, rec)
                manifest.write()
        elif todo:         # finished when first looked at, damaged since: next time
            for t, _ in todo:
                manifest.failed(t.name, "its files changed while the batch started")
                failed.append(t.name)
        else:
            log(f"batch: all {len(tasks)} tasks are finished")
        pooled = _pool(plan, records) if plan.compare else {}
        if pooled:
            manifest.data["pooled"] = pooled
        manifest.write()
    if failed:
        raise BatchError(_failed_message(failed, len(tasks),
                                         manifest.data["tasks"][failed[0]]["error"],
                                         manifest.path),
                         pooled=pooled, manifest=manifest.data)
    return BatchResult(plan=plan, manifest=manifest.data, ran=ran, skipped=skipped,
                       failed=failed, pooled=pooled, seconds=time.perf_counter() - t0,
                       dashboard=dashboard, workers=nworkers,
                       task_seconds=t_tasks or 0.0,
                       startup_seconds=(t_start if t_start is not None
                                        else time.perf_counter()) - t0)


def _finished(plan, record):
    """True when a task's ``record`` (or None) says it needs nothing more."""
    return record is not None and (not plan.compare or all(
        f in record.get("reports", {}) for f in plan.fitters))


def _check_positive(name, value):
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ParameterError(f"'{name}' must be an integer >= 1, got {value!r}")
    return value


def _outputs_not_inputs(plan):
    """Refuse a batch one of whose task files is a file its scenes read (any
    spelling or link): resumed or extended, a task had replaced the scene's
    background map (a probe; the check by name ran only without a manifest)."""
    inputs = sorted({f for p in plan.points for f in scene_inputs(p.scene)})
    if not inputs:
        return
    real = {os.path.realpath(f): f for f in inputs}
    ids = {}
    for f in inputs:
        with contextlib.suppress(OSError):
            st = os.stat(f)
            ids[(st.st_dev, st.st_ino)] = f
    for t in plan.tasks():
        for kind, path in t.paths:
            hit = real.get(os.path.realpath(path))
            if hit is None and ids and os.path.lexists(path):
                with contextlib.suppress(OSError):
                    st = os.stat(path)
                    hit = ids.get((st.st_dev, st.st_ino))
            if hit is not None:
                raise ParameterError(
                    f"'out': task {t.name}'s {kind} file {path!r} is {hit!r}, a file the "
                    f"scene reads; it is never replaced: use another output directory")


def _checked_against_manifest(plan):
    """``plan``, refused if the directory holds another batch's manifest or if a
    task's file is one the scenes read (:func:`_outputs_not_inputs`); a drawn seed
    is replaced by the one the manifest recorded (the same batch, resumed)."""
    _outputs_not_inputs(plan)
    existing = read_manifest(plan.out_dir) if os.path.isdir(plan.out_dir) else None
    if existing is None:
        if os.path.isdir(plan.out_dir):
            # no manifest: files under the batch's names are not the batch's
            clash = [p for t in plan.tasks() for _, p in t.paths if os.path.lexists(p)]
            if clash:
                raise ParameterError(
                    f"'out': {plan.out_dir!r} holds {len(clash)} file(s) named like this "
                    f"batch's outputs but no batch manifest (first: "
                    f"{os.path.basename(clash[0])!r}); they are never replaced: use an "
                    f"empty or new output directory")
        return plan
    if plan.seed_source == "drawn" and existing.get("seed_source") == "drawn":
        plan = dataclasses.replace(plan, batch_seed=int(existing["batch_seed"]))
    check_same_batch(existing, plan.identity(), plan.out_dir)
    return plan


def _warm_workers(client, fitters, log):
    """Run :func:`warm_worker` on every worker, in parallel; a worker where it
    fails is left cold (its first task makes the same imports and reports the
    error in its own record)."""
    try:
        took = client.run(warm_worker, tuple(fitters), on_error="return")
    except Exception as exc:                # noqa: BLE001 - an optimisation only
        log(f"batch: worker warm-up skipped ({_one_line(exc)})")
        return
    secs = [v for v in took.values() if isinstance(v, float)]
    if secs:
        log(f"batch: {len(secs)} workers warmed (imports, {max(secs):.1f} s)")


def _dashboard(client, cluster):
    """dask's dashboard link, or None when no dashboard is served."""
    if cluster is not None and importlib.util.find_spec("bokeh") is None:
        return None
    with contextlib.suppress(Exception):
        return client.dashboard_link
    return None


def _submit_and_collect(client, todo, manifest, records, ran, failed, retries,
                        progress, total, done, on_result):
    """Submit ``todo`` and record each task as it finishes; cancel on interrupt."""
    from dask.distributed import as_completed
    from scenesim.run import progress_bar
    token = secrets.token_hex(4)
    futures = {}
    warned = set()
    for t, grade_only in todo:
        fut = client.submit(run_task, t, grade_only=grade_only, pure=False,
                            retries=retries, key=f"scenesim-{t.name}-{token}")
        futures[fut] = t
    bar = progress_bar(total, "task", "batch") if progress and todo else None
    if bar is not None:
        bar.update(done)
    try:
        for fut in as_completed(list(futures), loop=client.loop):
            t = futures.pop(fut)
            try:
                rec = fut.result()
            except Exception as exc:            # noqa: BLE001 - recorded, batch goes on
                manifest.failed(t.name, _one_line(exc))
                failed.append(t.name)
            else:
                for message in rec.get("warnings", ()):      # each said once
                    if message not in warned:
                        warned.add(message)
                        warnings.warn(message, ScenesimWarning, stacklevel=2)
                manifest.done(t.name, rec)
                records.append(rec)
                ran.append(t.name)
                if on_result is not None:
                    on_result(t, rec)
            fut.release()
            manifest.write(every=1.0)
            if bar is not None:
                bar.update(1)
    except BaseException:
        with contextlib.suppress(Exception):
            client.cancel(list(futures), force=True)
        raise
    finally:
        if bar is not None:
            bar.close()
