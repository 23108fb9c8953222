"""Reference benchmarks: run time as a ratio to the random-number floor (DESIGN.md §7).

Absolute times drift on a shared machine, so every number is reported next to a
baseline measured in the same run, with the same number of threads:

* the **random-number floor** of a workload is the time to draw, in bulk, the variates
  its exact model cannot avoid.  Per materialised read: one float32 normal per pixel
  (white noise); one normal per kept time-line sample of each enabled 1/f series
  (correlated pink: ``frame_samples``; uncorrelated pink: ``n_out * frame_samples``;
  ACN: ``2 * n_out * frame_samples / 2``; picture frame: ``ny + nfoh``).  Per
  integration: one normal per pixel for kTC when enabled.  Per read interval: one
  Poisson draw per pixel with charge, at the workload's typical (median) mean
  ``lambda``.  The draws are split evenly across the threads, each thread with its own
  ``Generator`` from ``SeedSequence.spawn``, filling its part of a preallocated,
  pre-touched float32 buffer (reused in slabs of at most ``_SLAB`` variates so the
  floor itself needs bounded memory); Poisson draws go through the same slabs.
* the ramp **fit** is not random-number bound: its baseline is the memory-bandwidth
  time of reading the resultant cube once (``np.sum``), labelled as such.

Each case runs in a fresh ``spawn`` subprocess, so ``ru_maxrss`` is the peak resident
memory of that case alone (it includes the ~100 MB of the interpreter and imports,
reported separately as ``base_rss``).  The floor is measured in the parent process
right after the case.

Reference numbers of other programs (from their authors / our earlier measurements,
not re-measured here): the original NG program (Rauscher 2015) takes 5.5 s for 1 frame,
54 s and 2.5 GB for 10 frames, 7 min and 9.5 GB for 40 frames of a 4-output H2RG;
romanisim 0.15 L1 takes 83-108 s and 3.4 GB for a full 4096x4096 exposure; stcal 1.20
ramp fitting of 2048x2048x20 takes ~11 s (C OLS) and 57-95 s (likelihood).
"""

import json
import multiprocessing as mp
import os
import resource
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from noise.errors import ParameterError

__all__ = ["WORKLOADS", "main", "floor_seconds", "floor_counts", "run_case"]

_SLAB = 1 << 24          # variates per floor slab (64 MB of float32)
_MB = 1024.0             # ru_maxrss is in KiB on Linux

#: Reference numbers of other programs, used for the comparison columns.
REFERENCES = {
    ("noise", 1): ("NG original", 5.5, None),
    ("noise", 10): ("NG original", 54.0, 2500.0),
    ("noise", 40): ("NG original", 420.0, 9500.0),
    ("roman", "full"): ("romanisim 0.15 L1", 83.0, 3400.0),
    ("fit", "ols"): ("stcal 1.20 C OLS", 11.0, None),
    ("fit", "gls"): ("stcal 1.20 likelihood", 57.0, None),
}


# ------------------------------------------------------------------------- floor
def floor_seconds(n_normal, n_poisson, lam, threads, *, repeats=3, sampler="numpy"):
    """Random-number floor: seconds to draw the unavoidable variates in bulk.

    Parameters
    ----------
    n_normal : int
        float32 standard normals.
    n_poisson : int
        Poisson draws.
    lam : float
        Mean of the Poisson draws (e-), the workload's typical value (>= 0).
    threads : int
        Threads; the draws are split evenly, one independent Generator per thread.
    repeats : int, keyword-only
        Measure this many times and keep the fastest (the machine is shared; the
        minimum is the least disturbed estimate, which makes ratios conservative).
    sampler : {'numpy', 'scenesim'}, keyword-only
        Samplers: numpy's ``Generator.standard_normal`` and ``Generator.poisson``
        (DESIGN.md section 7, the reported floor), or the faster exact samplers the
        simulator uses, :func:`noise.fast.normal.standard_normal` and
        :func:`noise.fast.poisson.poisson` (a floor that credits the simulator with nothing
        it does not do).

    Returns
    -------
    float
        Wall seconds (page faults of the buffers are excluded by pre-touching).
    """
    n_normal, n_poisson, threads = int(n_normal), int(n_poisson), int(threads)
    if n_normal < 0 or n_poisson < 0:
        raise ParameterError(f"'n_normal' and 'n_poisson' must be >= 0, got "
                             f"{n_normal}, {n_poisson}")
    if not np.isfinite(lam) or lam < 0:
        raise ParameterError(f"'lam' must be finite and >= 0, got {lam!r}")
    if threads < 1:
        raise ParameterError(f"'threads' must be >= 1, got {threads!r}")
    if sampler not in ("numpy", "scenesim"):
        raise ParameterError(f"'sampler' must be 'numpy' or 'scenesim', got {sampler!r}")
    from noise.fast.normal import standard_normal
    from noise.fast.poisson import poisson
    gens = [np.random.Generator(np.random.PCG64(s))
            for s in np.random.SeedSequence(12345).spawn(threads)]
    slab = min(_SLAB, max(n_normal, n_poisson, 1))
    per = -(-slab // threads)
    bufs = [np.ones(per, dtype=np.float32) for _ in range(threads)]   # pre-touched
    lam_arr = [np.full(min(per, 1 << 20), lam, dtype=np.float64) for _ in range(threads)]

    def normal_part(t, n):
        if sampler == "numpy":
            gens[t].standard_normal(out=bufs[t][:n], dtype=np.float32)
        else:
            standard_normal(gens[t], bufs[t][:n])

    def poisson_part(t, n):
        # numpy has no `out=` for poisson: draw in 1M pieces (the int64 temporaries are
        # recycled by the allocator) and store them as float32 like the normals
        buf, la = bufs[t], lam_arr[t]
        for a in range(0, n, la.size):
            b = min(n, a + la.size)
            buf[a:b] = (gens[t].poisson(la[:b - a]) if sampler == "numpy"
                        else poisson(gens[t], la[:b - a]))

    def run(fn, total, pool):
        done = 0
        while done < total:
            n = min(slab, total - done)
            parts = [n // threads + (1 if t < n % threads else 0) for t in range(threads)]
            if pool is None:
                fn(0, parts[0])
            else:
                list(pool.map(fn, range(threads), parts))
            done += n

    pool = ThreadPoolExecutor(threads) if threads > 1 else None
    try:
        best = np.inf
        for _ in range(max(1, int(repeats))):
            t0 = time.perf_counter()
            run(normal_part, n_normal, pool)
            if n_poisson:
                run(poisson_part, n_poisson, pool)
            best = min(best, time.perf_counter() - t0)
        return best
    finally:
        if pool is not None:
            pool.shutdown()


def _noise_normals_per_read(det, params):
    """Unavoidable normals of one materialised read of the noise model (no kTC)."""
    nout = det.n_out_active
    L = det.frame_samples
    n = det.ny * det.nx if params.enabled("rd_noise") else 0
    if params.c_pink > 0:
        n += L
    if params.enabled("u_pink"):
        n += int(np.count_nonzero(params.per_output("u_pink", nout) > 0)) * L
    if params.enabled("acn"):
        n += int(np.count_nonzero(params.per_output("acn", nout) > 0)) * 2 * (L // 2)
    if params.pca0 > 0:
        n += det.ny + det.nfoh
    return n


def floor_counts(det, params, n_reads, nints=1, charged=0, n_intervals=0):
    """Variates the exact model cannot avoid.

    Parameters
    ----------
    det : noise.Detector
    params : noise.NoiseParams or None
        ``None``: no noise.
    n_reads : int
        Materialised reads in total (all integrations).
    nints : int
        Integrations (one kTC normal per pixel each, when kTC is on).
    charged : int
        Pixels with charge.
    n_intervals : int
        Read intervals in total (all integrations).

    Returns
    -------
    (int, int)
        Normals and Poisson draws.
    """
    n_normal = 0
    if params is not None:
        n_normal = n_reads * _noise_normals_per_read(det, params)
        if params.ktc > 0:
            n_normal += nints * det.ny * det.nx
    return int(n_normal), int(charged) * int(n_intervals)


# --------------------------------------------------------------------- workloads
def _cpu_seconds():
    """CPU seconds of this process and of its reaped children (the forked helper of
    small frames, :mod:`noise.fast.producer`)."""
    own = time.process_time()
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own + kids.ru_utime + kids.ru_stime


def _timed(fn):
    t0, c0 = time.perf_counter(), _cpu_seconds()
    out = fn()
    return time.perf_counter() - t0, _cpu_seconds() - c0, out


def _typical_lambda(rate, dt):
    """Median Poisson mean (e-) over the pixels with charge, for intervals ``dt`` (s)."""
    r = rate[rate > 0]
    return float(np.median(r) * dt) if r.size else 0.0


def bench_noise(frames, threads):
    """NG-default 4-output H2RG, ``frames`` reads streamed to FITS as uint16 DN (gain 1),
    the format the original program writes."""
    import noise
    det, params = noise.preset("H2RG"), noise.NoiseParams()
    gen = noise.NoiseGenerator(det, params, rng=1, threads=threads)
    with tempfile.TemporaryDirectory() as tmp:
        wall, cpu, _ = _timed(lambda: noise.write_noise_fits(
            os.path.join(tmp, "noise.fits"), gen, frames, unit="DN", gain=1.0))
    nn, npo = floor_counts(det, params, frames)
    return dict(wall=wall, cpu=cpu, n_normal=nn, n_poisson=npo, lam=0.0,
                detail=f"H2RG 2048x2048, 4 outputs, {frames} frames, NG defaults, "
                       f"uint16 DN to FITS")


def _run_engine(det, readout, rate, threads, noise_params, *, options=None,
                on_resultant=None):
    """Run a ChargeEngine (to a temp FITS file unless ``on_resultant`` is given: then
    each :class:`scenesim.engine.Resultant` goes to it)."""
    from scenesim.engine import ChargeEngine, EngineOptions
    from scenesim.run import write_exposure
    opts = options if options is not None else EngineOptions(threads=threads)
    eng = ChargeEngine(det, readout, noise_params=noise_params, rate=rate, rng=7,
                       options=opts)
    if on_resultant is not None:
        def consume():
            with eng.simulate() as run:
                for res in run:
                    on_resultant(res)
        return _timed(consume), eng
    with tempfile.TemporaryDirectory() as tmp:
        return _timed(lambda: write_exposure(eng, os.path.join(tmp, "exp.fits"))), eng


def _engine_result(det, readout, rate, params, timing, detail):
    wall, cpu, _ = timing
    nints = readout.nints
    n_reads = nints * len(readout.needed_reads)
    charged = int(np.count_nonzero(rate[~det.reference_mask()] > 0))
    nn, npo = floor_counts(det, params, n_reads, nints, charged, n_reads)
    return dict(wall=wall, cpu=cpu, n_normal=nn, n_poisson=npo,
                lam=_typical_lambda(rate, det.frame_time), detail=detail,
                pixel_reads=int(det.ny * det.nx * n_reads))


def _star_rates(shape, n, rng, log_flux):
    """Rate map (e-/s) of ``n`` point sources with log10 flux uniform in ``log_flux``."""
    ny, nx = shape
    x, y = rng.uniform(0, nx - 1, n), rng.uniform(0, ny - 1, n)
    flux = 10 ** rng.uniform(*log_flux, n)
    from scenesim.sky.psf import GaussianPSF, render_point_sources
    return render_point_sources(shape, x, y, flux, GaussianPSF(2.0))[0]


def bench_jwst(size, threads):
    """H2RG star field: 1000 stars over 4 decades, RAPID, full noise."""
    import noise
    from scenesim.detector.readout import Readout
    quick = not size.startswith("full")
    engine_only = size.endswith("engine")
    det = noise.preset("H2RG", naxis1=512, naxis2=512) if quick else noise.preset("H2RG")
    ngroups = 5 if quick else 20
    ro = Readout.named("RAPID", ngroups)
    rate = 0.5 + 0.01 + _star_rates(det.shape, 1000, np.random.default_rng(3), (1, 5))
    params = noise.NoiseParams()
    timing, _ = _run_engine(det, ro, rate, threads, params,
                            on_resultant=(lambda res: None) if engine_only else None)
    return _engine_result(det, ro, rate, params, timing,
                          f"H2RG {det.ny}x{det.nx}, 1000 stars 10-1e5 e-/s, bg 0.5, "
                          f"dark 0.01, RAPID x {ngroups}, full noise, "
                          + ("charge engine only" if engine_only
                             else "whole exposure (uncal file written)"))


def bench_roman(size, threads):
    """H4RG-10 with a 9-resultant / 44-read MA table, 0.5 % bright pixels, full noise."""
    import noise
    from scenesim.detector.readout import ROMAN_LIKE_TABLE, Readout
    quick = size != "full"
    det = noise.preset("H4RG-10", naxis1=1024, naxis2=1024) if quick \
        else noise.preset("H4RG-10")
    ro = Readout.from_ma_table(ROMAN_LIKE_TABLE)
    g = np.random.default_rng(4)
    rate = np.ones(det.shape)
    bright = g.random(det.shape) < 0.005
    rate[bright] = g.uniform(100, 1000, int(bright.sum()))
    params = noise.NoiseParams()
    timing, _ = _run_engine(det, ro, rate, threads, params)
    return _engine_result(det, ro, rate, params, timing,
                          f"H4RG-10 {det.ny}x{det.nx}, 9 resultants / 44 reads, bg 1 "
                          f"e-/s + 0.5% at 100-1000 e-/s, full noise")


def bench_timeseries(nints, threads):
    """64x64 window, ``nints`` integrations of RAPID x 5, one star, full noise."""
    import noise
    from scenesim.detector.readout import Readout
    det = noise.preset("H2RG").window(992, 992, 64, 64, name="BENCH64")
    ro = Readout.named("RAPID", 5, nints=nints)
    from scenesim.sky.psf import GaussianPSF, render_point_sources
    rate = 0.51 + render_point_sources(det.shape, 31.5, 31.5, 1e4, GaussianPSF(2.0))[0]
    params = noise.NoiseParams()
    timing, _ = _run_engine(det, ro, rate, threads, params)
    return _engine_result(det, ro, rate, params, timing,
                          f"64x64 window, {nints} ints x RAPID 5, 1 star 1e4 e-/s, "
                          f"full noise")


def bench_fit(spec, threads):
    """Ramp fit of ``size`` x ``size`` x 20 RAPID resultants with one fitter."""
    import noise
    from scenesim.rampfit import fit_ramps
    size, fitter = spec
    ngroups, rate, rn = 20, 10.0, 10.0
    tf = noise.preset("H2RG").frame_time
    g = np.random.default_rng(6)
    cube = np.empty((ngroups, size, size), dtype=np.float32)
    acc = np.zeros((size, size), dtype=np.float32)
    for k in range(ngroups):
        acc += g.poisson(rate * tf, (size, size)).astype(np.float32)
        cube[k] = acc + np.float32(rn) * g.standard_normal((size, size), dtype=np.float32)
    times = [np.array([(k + 1) * tf]) for k in range(ngroups)]
    t0 = time.perf_counter()
    cube.sum(dtype=np.float64)
    baseline = time.perf_counter() - t0
    wall, cpu, res = _timed(lambda: fit_ramps(cube, times, read_noise=rn, fitter=fitter,
                                              threads=threads))
    slope = np.asarray(res.slope, dtype=np.float64)
    return dict(wall=wall, cpu=cpu, baseline=baseline,
                baseline_kind="memory bandwidth: one np.sum over the cube",
                detail=f"{size}x{size}x{ngroups}, 10 e-/s, 10 e- per read, {fitter}",
                median_slope=float(np.nanmedian(slope)))


#: Approximation options measured by ``bench options`` (the exact path is the default).
OPTION_CASES = ("exact", "gauss_above=1000", "gauss_above=100", "arrivals=2d")


def _engine_options(case, threads):
    from scenesim.engine import EngineOptions
    if case == "exact":
        return EngineOptions(threads=threads)
    key, value = case.split("=")
    if key == "gauss_above":
        return EngineOptions(gauss_above=float(value), threads=threads)
    return EngineOptions(arrivals=value, threads=threads)


def _options_scene(size):
    """Detector, readout, rate map and white-noise params of the options workload."""
    import noise
    from scenesim.detector.readout import Readout
    det = noise.preset("H2RG", naxis1=size, naxis2=size)
    ro = Readout.named("RAPID", 10)
    # 0.1 .. 1e3 e-/s: up to ~2.8e4 e- over 10 reads at 1024^2, below the 16-bit ADC
    # ceiling at gain 1 (the metrics need unclipped ramps)
    rate = 10 ** np.random.default_rng(8).uniform(-1, 3, det.shape)
    # a bias offset keeps the ADC from clipping negative read noise at low charge
    params = noise.ZERO_NOISE.replace(rd_noise=noise.NoiseParams().rd_noise,
                                      bias_offset=1000.0)
    return det, ro, rate, params


def bench_options(case, threads):
    """One approximation against the exact path: run time and the slope errors.

    Same scene and seed for every case: rates log-uniform 0.1-1e3 e-/s, RAPID x 10,
    white read noise only (so the optimal variance is known exactly).  Each case
    is fitted with the GLS fitter; the metrics are computed per decade of true rate:
    slope bias and scatter in units of the optimal sigma, the mean reported chi2, and
    the largest per-pixel slope difference from the exact path (same seed) in units
    of the optimal sigma.
    """
    from scenesim.rampfit import fit_ramps, optimal_variance
    size = 1024 if case[1] == "full" else 256
    det, ro, rate, params = _options_scene(size)
    out = {}

    def keep(res):
        out[res.index] = res.dn.astype(np.float32)

    timing, eng = _run_engine(det, ro, rate, threads, params,
                              options=_engine_options(case[0], threads),
                              on_resultant=keep)
    res = np.stack([out[r] for r in range(ro.ngroups)])
    times = ro.read_times(det.frame_time)
    live = ~det.reference_mask()
    rn = params.rd_noise
    fit = fit_ramps(res, times, read_noise=rn, fitter="gls", jump_threshold=None,
                    threads=threads)
    truth = eng.rate
    sig = np.sqrt(optimal_variance(truth, times, rn))
    z = ((np.asarray(fit.slope, float) - truth) / sig)[live]
    chi = ((np.asarray(fit.slope, float) - truth) ** 2 / np.asarray(fit.var, float))[live]
    t = truth[live]
    decades = np.floor(np.log10(t)).astype(int)
    per = {}
    for d in np.unique(decades):
        m = decades == d
        per[int(d)] = dict(n=int(m.sum()), bias=float(z[m].mean()),
                           scatter=float(z[m].std()), chi2=float(chi[m].mean()))
    n_min = min(v["n"] for v in per.values())
    r = _engine_result(det, ro, rate, params, timing,
                       f"{size}x{size}, rates 0.1-1e3 e-/s log-uniform, RAPID x 10, "
                       f"white read noise {rn} e-, {case[0]}")
    r.update(per_decade=per, slope=np.asarray(fit.slope, np.float32)[live],
             sigma_opt=sig[live].astype(np.float32),
             max_abs_bias=max(abs(v["bias"]) for v in per.values()),
             max_scatter_dev=max(abs(v["scatter"] - 1) for v in per.values()),
             max_chi2_dev=max(abs(v["chi2"] - 1) for v in per.values()),
             # 1 sigma of a per-decade bias (in sigma units) and of the scatter ratio
             bias_noise=1 / np.sqrt(n_min), scatter_noise=1 / np.sqrt(2 * n_min))
    return r


def bench_pink(nframes, threads):
    """1/f synthesis accuracy: noise-only full H2RG, PSD deviation per decade."""
    import noise
    from noise import pink
    det = noise.preset("H2RG")
    params = noise.NoiseParams()
    gen = noise.NoiseGenerator(det, params, rng=1, threads=threads)

    def run():
        for _ in gen.frames(nframes):
            pass

    wall, cpu, _ = _timed(run)
    err = pink.measure_psd_error(rng=0)
    nn, npo = floor_counts(det, noise.NoiseParams(), nframes)
    return dict(wall=wall, cpu=cpu, n_normal=nn, n_poisson=npo, lam=0.0,
                psd_error=err, max_psd_dev=float(max(err["measured"].values())),
                max_design_dev=float(max(err["design"].values())),
                psd_z=float(max(err["measured"][k] / err["measured_sigma"][k]
                                for k in err["measured"])),
                kurtosis=float(err["measured_kurtosis"]),
                kurtosis_sigma=float(err["kurtosis_sigma"]),
                detail=f"H2RG 2048x2048 noise only (NG defaults), {nframes} frames "
                       f"in memory (peak RSS includes the PSD measurement)")


def bench_skips(case, threads):
    """What one skip saves: the same scene with the skip triggered and defeated.

    ``zero_amplitude``: white noise only with the other components at amplitude 0
    (skipped) vs at 1e-12 e- (computed, same output to 1e-11 e-).  ``no_charge``:
    100 stars on an otherwise empty 2048^2 array (only stamp pixels draw Poisson) vs
    1e-12 e-/s everywhere.  ``unused_frames``: DEEP8 (8 of 20 frames per group are
    read) vs a pattern that materialises all 20.  ``no_ramp_file``: the charge
    engine streaming to an exposure file vs keeping only the in-memory resultants.
    """
    import noise
    from scenesim.detector.readout import Readout
    what, defeated = case
    det = noise.preset("H2RG")
    ro = Readout.named("RAPID", 5)
    params = noise.ZERO_NOISE
    rate = np.zeros(det.shape)
    keep = None
    if what == "zero_amplitude":
        params = noise.ZERO_NOISE.replace(rd_noise=5.2)
        if defeated:
            params = params.replace(c_pink=1e-12, u_pink=1e-12, acn=1e-12, pca0=1e-12,
                                    pedestal=1e-12)
    elif what == "no_charge":
        rate = _star_rates(det.shape, 100, np.random.default_rng(5), (2, 4))
        rate[rate < 1e-3] = 0.0
        if defeated:
            rate = rate + 1e-12
    elif what == "unused_frames":
        params = noise.ZERO_NOISE.replace(rd_noise=5.2)
        rate = np.full(det.shape, 1.0)
        ro = Readout.named("DEEP8", 2)
        if defeated:
            ro = Readout.from_reads([list(range(g * 20, g * 20 + 20)) for g in range(2)])
    elif what == "no_ramp_file":
        params = noise.ZERO_NOISE.replace(rd_noise=5.2)
        rate = np.full(det.shape, 1.0)
        if not defeated:
            keep = lambda res: None  # noqa: E731  (in-memory resultants, no file)
    else:
        raise ParameterError(f"unknown skip case {what!r}")
    timing, _ = _run_engine(det, ro, rate, threads, params, on_resultant=keep)
    return _engine_result(det, ro, rate, params, timing,
                          f"{what}: {'skip defeated' if defeated else 'skipped'}")


#: Workload name -> (function, full cases, quick cases).
WORKLOADS = {
    "noise": (bench_noise, [10, 40, 88], [1, 5]),
    "jwst": (bench_jwst, ["full", "full-engine"], ["quick", "quick-engine"]),
    "roman": (bench_roman, ["full"], ["quick"]),
    "fit": (bench_fit, [(2048, f) for f in ("cds", "ols", "gls")],
            [(512, f) for f in ("cds", "ols", "gls")]),
    "timeseries": (bench_timeseries, [300], [30]),
    "options": (bench_options, [(c, "full") for c in OPTION_CASES],
                [(c, "quick") for c in OPTION_CASES]),
    "pink": (bench_pink, [10], [2]),
    "skips": (bench_skips, [(w, d) for w in ("zero_amplitude", "no_charge",
                                              "unused_frames", "no_ramp_file")
                            for d in (False, True)],
              [("zero_amplitude", False), ("zero_amplitude", True)]),
}


# ---------------------------------------------------------------------- running
def run_case(name, case, threads):
    """Run one case in this process; add peak and baseline RSS (MB) to its result."""
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / _MB
    out = WORKLOADS[name][0](case, threads)
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / _MB
    out["base_rss_mb"] = base
    return out


def _child(name, case, threads, queue):
    import noise  # noqa: F401  (imports count in base_rss, not in the case's peak)
    from noise.fast.memory import keep_freed_memory
    from scenesim import engine  # noqa: F401
    from scenesim.detector import readout  # noqa: F401
    from scenesim.io import exposure  # noqa: F401
    from scenesim.rampfit import fitter  # noqa: F401
    keep_freed_memory()            # as the scenesim command does (noise.fast.memory)
    try:
        queue.put(("ok", run_case(name, case, threads)))
    except BaseException as exc:  # report any failure to the parent, then exit
        queue.put(("error", f"{type(exc).__name__}: {exc}"))


def _in_subprocess(name, case, threads):
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    p = ctx.Process(target=_child, args=(name, case, threads, q))
    p.start()
    status, value = q.get()
    p.join()
    if status != "ok":
        raise RuntimeError(f"workload {name} {case!r} failed: {value}")
    return value


def _label(case):
    if isinstance(case, tuple) and isinstance(case[1], bool):
        return f"{case[0]} ({'defeated' if case[1] else 'skipped'})"
    if isinstance(case, tuple) and isinstance(case[0], str):
        return f"{case[0]} ({case[1]})"
    if isinstance(case, tuple):
        return f"{case[0]}x{case[0]} {case[1]}"
    if case is None:
        return "exact"
    return f"{case:g}" if isinstance(case, float) else str(case)


def _reference(name, case):
    key = (name, case[1]) if name == "fit" and case[0] == 2048 else (name, case)
    return REFERENCES.get(key)


def _row(name, case, r, threads):
    row = dict(workload=name, case=_label(case), threads=threads, **r)
    if name == "fit":
        row["ratio"] = r["wall"] / r["baseline"] if r["baseline"] > 0 else None
        row["ratio_kind"] = "time / memory-bandwidth baseline"
    else:
        row["floor"] = floor_seconds(r["n_normal"], r["n_poisson"], r["lam"], threads)
        row["ratio"] = r["wall"] / row["floor"] if row["floor"] > 0 else None
        if r["n_poisson"] or r["n_normal"]:
            f2 = floor_seconds(r["n_normal"], r["n_poisson"], r["lam"], threads,
                               sampler="scenesim")
            row["floor_scenesim"] = f2
            row["ratio_scenesim"] = r["wall"] / f2 if f2 > 0 else None
        row["ratio_kind"] = "time / random-number floor"
    ref = _reference(name, case)
    if ref is not None:
        prog, sec, mb = ref
        row["reference"] = prog
        row["speedup_vs_reference"] = sec / r["wall"]
        row["reference_mb"] = mb
    return row


def _fmt(v, f):
    return "-" if v is None else format(v, f)


def _markdown(rows):
    head = ("| workload | case | wall s | CPU s | peak RSS MB | floor s | ratio | "
            "vs reference | notes |\n|---|---|---|---|---|---|---|---|---|\n")
    lines = []
    for r in rows:
        base = r.get("floor", r.get("baseline"))
        kind = "floor" if "floor" in r else "np.sum"
        ref = "-"
        if "reference" in r:
            ref = f"{r['speedup_vs_reference']:.1f}x faster than {r['reference']}"
            if r.get("reference_mb"):
                ref += f" ({r['reference_mb']:.0f} MB)"
        notes = r["detail"]
        if r.get("ratio_scenesim"):
            notes += (f"; ratio {r['ratio_scenesim']:.1f} against a floor drawn with "
                      f"scenesim's own samplers ({r['floor_scenesim']:.2f} s)")
        if r.get("pixel_reads") and r.get("floor"):
            notes += (f"; {r['pixel_reads'] / r['wall'] / 1e6:.0f} Mpixel-reads/s "
                      f"(floor {r['pixel_reads'] / r['floor'] / 1e6:.0f})")
        if "max_abs_bias" in r:
            notes += (f"; speed-up vs exact {_fmt(r.get('speedup_vs_exact'), '.2f')}; "
                      f"per decade of rate: max abs(bias) {r['max_abs_bias']:.3f} sigma_opt"
                      f" (1 sigma {r['bias_noise']:.3f}), max abs(scatter/sigma_opt - 1) "
                      f"{r['max_scatter_dev']:.3f} (1 sigma {r['scatter_noise']:.3f}), "
                      f"max abs(chi2 - 1) {r['max_chi2_dev']:.3f}; max per-pixel slope "
                      f"difference from exact {_fmt(r.get('max_diff_sigma'), '.2f')} sigma_opt")
        if "max_psd_dev" in r:
            notes += (f"; 1/f PSD vs theory, max per decade 30 Hz-30 kHz: designed "
                      f"{r['max_design_dev']:.1e} dex, measured {r['max_psd_dev']:.3f} dex"
                      f" (at most {r['psd_z']:.1f} sigma of its sampling noise); kurtosis "
                      f"of first "
                      f"differences {r['kurtosis']:.4f} +- {r['kurtosis_sigma']:.4f}")
        lines.append(f"| {r['workload']} | {r['case']} | {r['wall']:.2f} | "
                     f"{r['cpu']:.2f} | {r['peak_rss_mb']:.0f} | {_fmt(base, '.2f')} "
                     f"({kind}) | {_fmt(r['ratio'], '.1f')} | {ref} | {notes} |")
    return head + "\n".join(lines) + "\n"


def _plot(rows, path):
    """Run time against error: one point per approximation option."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for r in rows:
        if r["workload"] == "options":
            err = max(r["max_abs_bias"], r["max_scatter_dev"], r["max_chi2_dev"])
            label = r["case"]
        elif r["workload"] == "pink":
            err = r["max_psd_dev"]
            label = "1/f synthesis (exact)"
        else:
            continue
        ax.scatter(r["wall"], max(err, 1e-4))
        ax.annotate(label, (r["wall"], max(err, 1e-4)), fontsize=8)
    ax.set_xlabel("run time (s)")
    ax.set_ylabel("error: max over decades of |bias|, |scatter-1|, |chi2-1|\n"
                  "(1/f: max PSD deviation per decade, dex)")
    ax.set_yscale("log")
    ax.set_title("run time against error (one point per option)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(workloads, *, quick=False, out_dir="bench_out", threads=None):
    """Run the named workloads (all if empty), write ``bench.json``/``.md``/``.png``.

    Parameters
    ----------
    workloads : sequence of str
        Names from :data:`WORKLOADS`; empty: all.
    quick : bool
        Small sizes (seconds instead of minutes).
    out_dir : str
        Output directory (created).
    threads : int or None
        Threads for the workloads and the floor (default: all cores).

    Returns
    -------
    int
        Exit status (0).
    """
    names = list(workloads) or list(WORKLOADS)
    bad = [n for n in names if n not in WORKLOADS]
    if bad:
        raise ParameterError(f"'workloads' must be among {list(WORKLOADS)}, got {bad}")
    threads = int(threads) if threads is not None else (os.cpu_count() or 1)
    if threads < 1:
        raise ParameterError(f"'threads' must be >= 1, got {threads}")
    os.makedirs(out_dir, exist_ok=True)
    rows = []
    exact = {}
    for name in names:
        fn, full, small = WORKLOADS[name]
        for case in (small if quick else full):
            print(f"[bench] {name} {_label(case)} ...", flush=True)
            r = _in_subprocess(name, case, threads)
            arrays = {k: r.pop(k) for k in ("slope", "sigma_opt") if k in r}
            row = _row(name, case, r, threads)
            if name == "options":
                _versus_exact(row, arrays, exact)
            rows.append(row)
            extra = f" floor {row['floor']:.2f} s" if "floor" in row else \
                f" np.sum {row['baseline']:.3f} s"
            print(f"[bench] {name} {_label(case)}: wall {row['wall']:.2f} s, cpu "
                  f"{row['cpu']:.2f} s, peak {row['peak_rss_mb']:.0f} MB,{extra}, "
                  f"ratio {_fmt(row['ratio'], '.1f')}", flush=True)
            _write(rows, out_dir, threads, quick)
    return 0


def _versus_exact(row, arrays, exact):
    """Options: the largest per-pixel slope difference from the exact case (same seed
    and scene), in units of the optimal sigma; and the speed-up over the exact case."""
    if row["case"].startswith("exact"):
        exact.update(arrays, wall=row["wall"])
        row["max_diff_sigma"] = 0.0
        row["speedup_vs_exact"] = 1.0
        return
    if "slope" in exact and "slope" in arrays:
        d = np.abs(arrays["slope"].astype(float) - exact["slope"]) / exact["sigma_opt"]
        row["max_diff_sigma"] = float(d.max())
        row["speedup_vs_exact"] = exact["wall"] / row["wall"]


def _write(rows, out_dir, threads, quick):
    meta = dict(threads=threads, quick=quick, nproc=os.cpu_count(),
                load_average=os.getloadavg(),
                python=sys.version.split()[0], numpy=np.__version__,
                date=time.strftime("%Y-%m-%d %H:%M:%S"))
    with open(os.path.join(out_dir, "bench.json"), "w") as f:
        json.dump(dict(meta=meta, rows=rows), f, indent=1)
    with open(os.path.join(out_dir, "bench.md"), "w") as f:
        f.write(f"Benchmarks ({meta['date']}, {threads} threads, "
                f"{'quick' if quick else 'full'})\n\n" + _markdown(rows))
    if any(r["workload"] in ("options", "pink") for r in rows):
        try:
            _plot(rows, os.path.join(out_dir, "bench.png"))
        except ImportError:
            print("[bench] matplotlib is not installed (pip install 'scenesim[plot]'): "
                  "no bench.png", flush=True)
