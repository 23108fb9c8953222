"""One realisation, made where the worker runs: simulate, fit, grade, record.

:func:`run_task` is what a dask worker executes.  It receives a
:class:`~scenesim.batch.plan.Task` (a scene, a seed and file names: a few kB) and
returns its record (a few kB: file names, sizes, checksums and the per-bin
comparison); the ramps never leave the worker, which streams them to its own files
as ``scenesim run`` does, so a worker needs the memory of one exposure.

The simulation is the one loop of :func:`scenesim.run.write_exposure` on the engine
of :func:`scenesim.run.build_engine`, with the header cards of ``scenesim run`` plus
the batch's (``BATCHSD``, ``BATCHKEY``, ``BATCHTSK``, ``BATCHDET``); so the arrays equal those of
``scenesim run SCENE --seed <seed>``.  The fits are
:func:`scenesim.calib.prepare.fit_exposure_file` (cds, ols, gls) and
:func:`scenesim.adapters.stcal.fit_exposure_stcal` (stcal-ols_c, stcal-likely) on
the ramp file, or on the resultants kept in memory when ``ramp = false``; the grade
is :func:`scenesim.validate.compare.compare_files`, as in ``scenesim run
--compare``.

Every file is written to a temporary file and renamed into place
(:mod:`noise.fitsio`), the record last: a task whose record exists and whose files
match it is finished; a worker killed mid-task leaves only temporary files (removed
by the batch) and the task is run again, from the start, by another worker.  Files
are replaced when a task is run again (the same seed makes the same arrays).
"""

import hashlib
import json
import os
import socket
import time
import warnings

from noise.errors import ParameterTypeError, ScenesimWarning
from noise.fast.memory import keep_freed_memory
from noise.validate import describe
from noise.fitsio import atomic_file
from scenesim.adapters.stcal import fit_exposure_stcal
from scenesim.calib.prepare import PrepareOptions, fit_exposure_file
from scenesim.engine import EngineOptions
from scenesim.io.header import psf_cards
from scenesim.run import build_engine, write_exposure
from scenesim.validate.compare import compare_files

__all__ = ["run_task", "warm_worker", "file_entry", "files_match", "batch_cards", "RECORD_FORMAT"]

#: The ``format`` of a task record.
RECORD_FORMAT = "scenesim-batch-task 1"


def batch_cards(task):
    """Header cards naming the batch seed, the spawn key, the task and, for a batch
    with ``[[detectors]]``, the task's detector (``BATCHDET``)."""
    cards = [("BATCHSD", task.batch_seed, "batch seed (SEED is spawned from it)"),
             ("BATCHKEY", ",".join(str(k) for k in task.spawn_key),
              "spawn key of SEED under BATCHSD"),
             ("BATCHTSK", task.name[:68], "scenesim batch task")]
    if task.detector:
        cards.append(("BATCHDET", task.detector[:68], "batch [[detectors]] name"))
    return cards


def file_entry(path, *, checksum=True):
    """``{'size', 'mtime_ns', 'sha256'}`` of the file ``path``."""
    st = os.stat(path)
    entry = {"size": st.st_size, "mtime_ns": st.st_mtime_ns}
    if checksum:
        h = hashlib.sha256()
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        entry["sha256"] = h.hexdigest()
    return entry


def files_match(entries, paths):
    """True when every file of ``entries`` (``{kind: file_entry}``) exists at
    ``paths[kind]`` with its size and modification time (or, if only the time
    changed, its checksum)."""
    for kind, entry in entries.items():
        path = paths.get(kind)
        if path is None:
            return False
        try:
            st = os.stat(path)
        except OSError:
            return False
        if st.st_size != entry["size"]:
            return False
        if st.st_mtime_ns != entry["mtime_ns"] and \
                file_entry(path)["sha256"] != entry.get("sha256"):
            return False
    return True


def _small_report(report):
    """The per-realisation comparison, without per-source lists and figures."""
    d = report.to_dict()
    phot = dict(d.get("photometry") or {})
    phot.pop("sources", None)
    return {"rows": d["rows"], "jumps": d.get("jumps") or {}, "photometry": phot,
            "notes": d.get("notes") or []}


def _fit(exposure, output, fitter, refpix, threads):
    options = PrepareOptions(refpix=refpix, threads=threads)
    if fitter.startswith("stcal-"):
        fit_exposure_stcal(exposure, output, algorithm=fitter[6:].upper(),
                           options=options, overwrite=True)
    else:
        fit_exposure_file(exposure, output, fitter=fitter, options=options,
                          overwrite=True)


def warm_worker(fitters=()):
    """Import, on a worker, what its tasks import on first use; return the seconds.

    The batch runs this on every worker once, before submitting the tasks
    (:func:`scenesim.batch.runner.run_batch`): the comparison's photometry
    (photutils) and, for stcal fitters, stcal.  Otherwise each worker's first task
    pays these imports (~1 CPU s), inside the throughput.
    """
    try:
        names = list(fitters)
    except TypeError:
        names = None
    if names is None or isinstance(fitters, str) or \
            not all(isinstance(f, str) for f in names):
        raise ParameterTypeError(f"'fitters' must be a list of fitter names, got "
                                 f"{describe(fitters)}")
    t0 = time.perf_counter()
    import photutils.aperture  # noqa: F401 - scenesim.validate.photometry, lazily
    import scenesim.pipelines.instrument  # noqa: F401 - scenesim.run, lazily
    import scenesim.pipelines.zeroframe  # noqa: F401
    if any(f.startswith("stcal-") for f in names):
        import stcal.ramp_fitting.ramp_fit  # noqa: F401 - scenesim.adapters.stcal
    return time.perf_counter() - t0


def run_task(task, *, grade_only=False):
    """Make one realisation and return its record (also written to ``record``).

    Parameters
    ----------
    task : scenesim.batch.plan.Task
    grade_only : bool
        The files exist (a finished task whose record lacks a comparison): only
        compare and write the record.

    Returns
    -------
    dict
        ``format``, ``name``, ``point``, ``realisation``, ``spawn_key``, ``seed``,
        ``batch_seed``, ``files`` (``{kind: {size, mtime_ns, sha256}}``, names
        relative to the record's directory in ``outputs``), ``reports`` (``{fitter:
        rows, jumps, photometry, notes}`` when comparing), ``seconds``, ``host``,
        ``pid``, ``warnings`` (the distinct messages of the project's own warnings
        the task raised, :class:`noise.errors.ScenesimWarning`).
    """
    # dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536 (memory handed
    # back to the kernel, then zeroed again on every exposure); the malloc policy of
    # the scenesim command instead (noise.fast.memory)
    keep_freed_memory()
    # the project's own warnings (a star off the array, a gain that rounds the noise
    # away) go back in the record, for the client to say once; others pass on
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        record = _run_task(task, grade_only)
    said = []
    for w in caught:
        if issubclass(w.category, ScenesimWarning):
            if str(w.message) not in said:
                said.append(str(w.message))
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    record["warnings"] = said
    with atomic_file(task.path["record"], overwrite=True) as fh:
        fh.write(json.dumps(record, indent=1, allow_nan=True).encode())
    return record


def _run_task(task, grade_only):
    """:func:`run_task`'s work: the record, not yet written."""
    t0 = time.perf_counter()
    paths = task.path
    exp_path = paths.get("exposure")
    truth_path = paths["truth"]
    scene = task.scene
    if not grade_only:
        engine, rendered = build_engine(scene, options=EngineOptions(threads=task.threads))
        cards = (list(scene.to_header_cards()) + psf_cards(scene.sources.psf)
                 + batch_cards(task))
        cfg = scene.output
        written = write_exposure(engine, exp_path, cards=cards, truth_path=truth_path,
                                 save_charge=cfg.save_charge, save_noise=cfg.save_noise,
                                 sources=rendered, overwrite=True,
                                 write_behind=not task.fitters)
        del engine
        exposure = exp_path if exp_path is not None else written["exposure"]
        del written
        for fitter in task.fitters:
            _fit(exposure, paths[fitter], fitter, task.refpix, task.threads)
        del exposure
    reports = {}
    if task.compare:
        for fitter in task.fitters:
            reports[fitter] = _small_report(compare_files(paths[fitter], truth_path,
                                                          exposure=exp_path))
    kinds = [k for k in paths if k != "record"]
    folder = os.path.dirname(paths["record"])
    record = {"format": RECORD_FORMAT, "name": task.name, "point": task.point,
              "realisation": task.realisation, "spawn_key": list(task.spawn_key),
              "seed": task.seed, "batch_seed": task.batch_seed,
              "outputs": {k: os.path.relpath(paths[k], folder) for k in kinds},
              "files": {k: file_entry(paths[k]) for k in kinds},
              "reports": reports, "seconds": time.perf_counter() - t0,
              "host": socket.gethostname(), "pid": os.getpid()}
    return record
