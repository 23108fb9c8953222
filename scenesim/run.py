"""Orchestrator: a validated :class:`~scenesim.scene.Scene` in, files out.

The one loop of a simulation (:func:`write_exposure`): the engine
(:meth:`scenesim.engine.ChargeEngine.simulate`) is the source, the files
(:class:`scenesim.io.exposure.ExposureWriter`) the sink; resultants are pulled from
the one and pushed to the other, so the sink never drives the source.
:func:`run_scene` builds the engine from a scene (:func:`build_engine`: the sky of
:mod:`scenesim.sky.rates`, the effects of :mod:`scenesim.detector`, the noise of
:mod:`noise`), runs that loop, then optionally fits the slopes
(:func:`scenesim.calib.prepare.fit_exposure_file`) and compares them with the truth
(:func:`scenesim.validate.compare.compare_files`).

Only the outputs asked for are made: with ``[output] ramp = false`` (slopes only) no
ramp file is written at all -- the resultants are kept in memory
(``write_exposure(engine, None)``) and fitted from there
(:func:`scenesim.calib.prepare.prepare_exposure` takes an in-memory
:class:`~scenesim.io.exposure.Exposure` whose header and read table are those the file
would have had, so the slopes equal those of a fit of the written file, bit for
bit).  Every output path, then the memory and disk the run needs
(:func:`scenesim.budget.check_budget`), is checked before any work starts.

Random streams: the scene seed is the root ``SeedSequence``; every part draws from
its own stream of the registry :mod:`noise.streams` (engine, noise, Poisson, cosmic
rays, hot pixels), so changing one part of a scene does not shift the draws of the
others.
"""

import contextlib
import dataclasses
import os
import time
from dataclasses import dataclass

import numpy as np

from noise import streams
from noise.clock import exposure_slots
from noise.errors import FileFormatError, ParameterError, ParameterTypeError
from noise.validate import describe
from scenesim.budget import check_budget
from scenesim.calib.prepare import PrepareOptions, fit_exposure_file
from scenesim.engine import ChargeEngine, EngineOptions
from scenesim.io.exposure import ExposureWriter
from scenesim.io.header import instrument_cards, psf_cards
from scenesim.progress import progress_bar
from scenesim.outputs import (check_outputs, check_plot_dir, clean_stale_temps,
                              fit_path_for, made_directory, scene_inputs)
from scenesim.validate.compare import compare_files
from scenesim.sky.maps import load_map
from scenesim.sky.rates import cosmic_ray_hits, scene_rates

__all__ = ["build_engine", "run_scene", "write_exposure", "RunResult", "progress_bar"]


@dataclass
class RunResult:
    """What a run produced: paths (None when not written), timings (s), and a note of
    the temporary files of dead runs removed from the output directories (or None)."""

    exposure: str | None
    truth: str | None
    fit: str | None
    report: object
    seconds: float
    engine: ChargeEngine
    cleaned: str | None = None
    #: JWST's zero frame of each integration (uint16 DN), kept when the run's
    #: products need it (a NIRCam uncal with NFRAMES > 1), else None
    zero_frame: np.ndarray | None = None


def write_exposure(engine, path, *, cards=(), truth_path=None, save_charge=False,
                   save_noise=False, sources=None, progress=None, overwrite=False,
                   zero_frame=False, write_behind=False):
    """Run ``engine`` and write what it makes: the exposure and the truth file.

    The loop of every simulation: resultants are pulled from the engine's run
    (:meth:`ChargeEngine.simulate`) and pushed to the sink
    (:class:`scenesim.io.exposure.ExposureWriter`), one at a time, so memory holds
    one resultant, not the ramp.  An error or interrupt leaves no output file and no
    temporary file behind.

    Parameters
    ----------
    engine : scenesim.engine.ChargeEngine
    path : str or None
        Exposure file; ``None`` writes no ramp file (truth and in-memory result only).
    cards : sequence of (key, value, comment)
        Extra primary-header cards (scene, seed, ...).
    truth_path : str or None
        Truth file; ``None`` writes none.
    save_charge, save_noise : bool
        Add the noise-free charge and the noise-only resultants to the truth file.
    sources : astropy.table.Table or None
        Rendered source catalogue for the truth file.
    progress : callable, optional
        Called with the number of reads done.
    overwrite : bool
        Replace existing files (default: refuse them).
    zero_frame : bool
        Keep the first read of each integration (``simulate(zero_frame=True)``).
    write_behind : bool
        Nothing in this process reads the exposure back: keep it out of the page
        cache as it is written (see :class:`scenesim.io.exposure.ExposureWriter`).

    Returns
    -------
    dict
        See :meth:`scenesim.io.exposure.ExposureWriter.finish`; with ``zero_frame``,
        also ``zero_frame`` (nints, ny, nx) uint16 DN.
    """
    with ExposureWriter(engine, path, cards=cards, truth_path=truth_path,
                        save_charge=save_charge, save_noise=save_noise, sources=sources,
                        overwrite=overwrite, write_behind=write_behind) as writer:
        with engine.simulate(save_charge=writer.save_charge, save_noise=writer.save_noise,
                             progress=progress, zero_frame=zero_frame) as run:
            for resultant in run:
                writer.add(resultant)
        out = writer.finish(run)
        if zero_frame:
            out["zero_frame"] = run.zero_frame
        return out


def build_engine(scene, *, options=EngineOptions()):
    """Everything needed to run ``scene``: ``(engine, rendered_catalogue)``.

    ``scene.seed`` must be set (see :meth:`Scene.ensure_seed`).
    """
    if scene.seed is None:
        raise ParameterError("'seed' must be set before building the engine; call "
                             "scene.ensure_seed()")
    det = scene.detector
    readout = scene.readout.build()
    seed = scene.seed
    rate, variable, rendered = scene_rates(scene)
    t_total = exposure_slots(readout.nints, readout.nreads) * det.frame_time
    crs = cosmic_ray_hits(scene, t_total)
    eff = scene.effects
    full_well = None
    if eff.full_well is not None:
        full_well = load_map(eff.full_well, det, name="full_well", allow_zero=False)
        if full_well.ndim == 2 and np.all(full_well == full_well.flat[0]):
            full_well = np.float64(full_well.flat[0])
    nl = eff.nonlinearity_model()
    if full_well is not None and not nl.is_linear:
        nl.check_monotonic(float(np.max(full_well)))
    engine = ChargeEngine(
        det, readout, noise_params=scene.noise, rate=rate, variable_sources=variable,
        cosmic_rays=crs, full_well=full_well, nonlinearity=nl, ipc_kernel=eff.ipc(),
        gain=eff.gain, adc_bits=eff.adc_bits,
        rng=np.random.SeedSequence(seed, spawn_key=streams.ENGINE), options=options)
    return engine, rendered


def _output_config(cfg, **overrides):
    """The scene's ``[output]`` with the non-None ``overrides`` (``path`` from
    ``output``, ``fit``, ``refpix``, ``compare``) applied."""
    out = overrides.get("output")
    if out is not None and not isinstance(out, (str, os.PathLike)):
        raise ParameterTypeError(f"'output' must be a path (str or os.PathLike) or None, "
                                 f"got {describe(out)}")
    changes = {("path" if k == "output" else k): (os.fspath(v) if k == "output" else v)
               for k, v in overrides.items() if v is not None}
    return dataclasses.replace(cfg, **changes) if changes else cfg


def _output_paths(scene, cfg, *, overwrite, plots):
    """``(exposure, truth, fit)`` paths of a run (None: not written), checked before
    any work (:func:`scenesim.outputs.check_outputs`).  Slopes only (``ramp =
    false``): no ramp file at all."""
    exp_path = cfg.path if cfg.ramp else None
    if not cfg.ramp and not cfg.fit and not cfg.truth:
        raise ParameterError("nothing to write: set [output] ramp, truth or fit")
    if cfg.fit and scene.readout.build().ngroups < 2:
        raise ParameterError(
            f"[output] 'fit' = {cfg.fit!r}: a one-group exposure (ngroups = 1) has no "
            f"slope to fit; use ngroups >= 2 or drop the fit")
    truth_path = cfg.truth_path if cfg.truth else None
    fit_path = None
    if cfg.fit:
        fit_path = fit_path_for(cfg.path, cfg.fit)
    check_outputs({"exposure": exp_path, "truth file": truth_path, "fit file": fit_path},
                  inputs=scene_inputs(scene), overwrite=overwrite)
    if plots is not None:
        if not isinstance(plots, (str, os.PathLike)):
            raise ParameterTypeError(f"'plots' must be a directory path or None, got "
                                     f"{describe(plots)}")
        check_plot_dir(plots, inputs=scene_inputs(scene), overwrite=overwrite)
    return exp_path, truth_path, fit_path


@contextlib.contextmanager
def _about_scene(scene, *, tables_only=False):
    """Errors in the block name the scene file first, as the loader's do (a map's
    values, the scene's own output names, a one-group readout with a fit);
    ``tables_only``: only those about a scene table (``[output] 'fit' ...``)."""
    try:
        yield
    except (ParameterError, FileFormatError) as exc:
        if scene.path is None or str(exc).startswith(scene.path) or (
                tables_only and not str(exc).startswith("[")):
            raise
        raise type(exc)(f"{scene.path}: {exc}") from exc


@contextlib.contextmanager
def _progress(nreads, enabled):
    """A progress callback (reads done) drawing a bar on long runs, or None."""
    if not enabled or nreads < 20:
        yield None
        return
    bar = progress_bar(nreads, "read", "simulate")
    try:
        yield lambda n: bar.update(n - bar.n)          # drawn at most every 0.1 s
    finally:
        bar.close()


def run_scene(scene, *, output=None, seed=None, options=EngineOptions(), progress=True,
              fit=None, refpix=None, compare=None, plots=None, overwrite=False,
              force=False, products=()):
    """Run ``scene``: simulate, write the exposure and truth, then fit and compare.

    Parameters
    ----------
    scene : Scene
    output : str, optional
        Exposure path (overrides ``[output] path``).
    seed : int, optional
        Overrides the scene's seed.
    progress : bool
        Show a progress bar on long runs (tqdm, on stderr).
    fit, refpix, compare : optional
        Override ``[output] fit``, ``refpix`` and ``compare``.
    plots : str, optional
        Directory for the comparison's PNG figures.
    overwrite : bool
        Replace existing outputs (never a file the scene reads, never a read-only
        one; :mod:`scenesim.outputs`).  Every output is checked before any work.
    force : bool
        Run even when the estimated memory or output exceeds what the machine has
        (:func:`scenesim.budget.check_budget`, checked after the output paths and
        before any work); the limit exceeded is then a
        :class:`~scenesim.budget.BudgetWarning`, as is a run that uses more than half
        of either.
    products : sequence of {'uncal', 'l1', 'reffiles'}
        Pipeline products the caller writes after the run (``scenesim run --uncal
        --l1 --reffiles``): counted in the size check's output estimate only.

    Returns
    -------
    RunResult

    Raises
    ------
    noise.errors.ParameterError
        Bad outputs, or (without ``force``) a run the machine cannot hold: one line
        with the estimate, the limit and the scene keys that drive it.
    """
    t0 = time.perf_counter()
    out_cfg = _output_config(scene.output, output=output, fit=fit, refpix=refpix,
                             compare=compare)
    if seed is not None:
        scene = scene.replace(seed=seed)
    scene = scene.ensure_seed().replace(output=out_cfg)
    with _about_scene(scene, tables_only=output is not None):   # -o: not the scene's
        exp_path, truth_path, fit_path = _output_paths(scene, out_cfg,
                                                       overwrite=overwrite, plots=plots)
    check_budget(scene, force=force, options=options, products=products).warn()
    cleaned = clean_stale_temps([exp_path, truth_path, fit_path])
    with _about_scene(scene):
        engine, rendered = build_engine(scene, options=options)
    cards = list(scene.to_header_cards()) + psf_cards(scene.sources.psf) + \
        instrument_cards(scene.instrument)
    ro = engine.readout
    zero = "uncal" in products and _needs_zero_frame(scene, engine)
    with _progress(ro.nints * len(ro.needed_reads), progress) as cb:
        written = write_exposure(engine, exp_path, cards=cards, truth_path=truth_path,
                                 save_charge=out_cfg.save_charge,
                                 save_noise=out_cfg.save_noise, sources=rendered,
                                 progress=cb, overwrite=overwrite, zero_frame=zero,
                                 # nothing reads the exposure back: no fit, and no
                                 # pipeline product made from it afterwards
                                 write_behind=not out_cfg.fit and not products)
    zero = written.get("zero_frame")
    report = None
    if out_cfg.fit:
        # slopes only (ramp = false): the resultants were kept in memory
        exposure = exp_path if exp_path is not None else written["exposure"]
        del written
        fit_exposure_file(exposure, fit_path, fitter=out_cfg.fit, overwrite=overwrite,
                          options=PrepareOptions(refpix=out_cfg.refpix))
        del exposure
        if out_cfg.compare and truth_path is not None:
            with made_directory(plots):
                report = compare_files(fit_path, truth_path, plots=plots,
                                       exposure=exp_path)
    return RunResult(exp_path, truth_path, fit_path, report, time.perf_counter() - t0,
                     engine, cleaned, zero)


def _needs_zero_frame(scene, engine):
    """True when the JWST uncal of this run carries a zero frame (a NIRCam
    MULTIACCUM pattern with ``NFRAMES > 1``, :mod:`scenesim.pipelines.zeroframe`)."""
    from scenesim.pipelines.instrument import resolve_instrument
    from scenesim.pipelines.zeroframe import has_zero_frame
    ident = resolve_instrument(scene.instrument, engine.detector, engine.readout.name)
    return has_zero_frame(engine.readout, ident["name"])

