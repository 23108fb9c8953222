"""The benchmark workloads: what is timed, on which scene, and with what floor.

Each workload is a function ``bench_<name>(case, threads)`` returning a dict of its
wall and CPU times, its floor counts (and, for the simulation workloads, its kept 1/f
samples and output bytes for the limit of :mod:`scenesim.bench.limit`) and details;
:data:`WORKLOADS` maps each name to its function and cases (full and ``--quick``).
The simulation workloads run the charge engine (``ChargeEngine.simulate``) to a FITS
file as a user's run would; the fit workload times :func:`scenesim.rampfit.fit_ramps`
on a cube loaded from a file that the runner prepares once per size
(:data:`PREPARE`, :func:`fit_input`), the very file the stcal peer fits
(:mod:`scenesim.bench.peers`).  :func:`roman_scene` and :func:`fit_input` are the
inputs the peers share.

The fit's **scaling** cases ``(size, 'gls', nres)`` (issue 16) fit ``nres``
resultants of a ``size`` x ``size`` exposure file (:func:`write_fit_ramp`: uint16 DN
in the ``SCI`` cube, one file per size holding the run's longest ramp) read by row
blocks (:func:`scenesim.io.cuberows.exposure_rows`): the cube is never in memory,
so the process's peak memory is what the streamed fit needs.  Beside the fit they
time, in the same process, one read of the cube by the same row blocks and one
``np.sum`` of each block (the memory-bandwidth baseline).
"""

import os
import resource
import tempfile
import time

import numpy as np

import noise
from noise import pink
from noise.errors import ParameterError
from noise.fitsio import StreamingFITS
from scenesim.bench.process import peak_rss_self
from scenesim.bench.floor import floor_counts, typical_lambda
from scenesim.bench.limit import pink_samples

__all__ = ['WORKLOADS', 'OPTION_CASES', 'PREPARE', 'FIT_JUMP_SIGMA', 'bench_noise',
           'bench_jwst', 'bench_roman', 'bench_timeseries', 'bench_fit', 'bench_options',
           'bench_pink', 'bench_skips', 'roman_scene', 'fit_input', 'prepare_fit',
           'write_fit_ramp', 'fit_scaling_cases', 'FIT_SCALING_SIZES',
           'FIT_SCALING_NRES']


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


def bench_noise(frames, threads):
    """NG-default 4-output H2RG, ``frames`` reads streamed to FITS as uint16 DN (gain 1),
    the format the original program writes."""
    det, params = noise.preset("H2RG"), noise.NoiseParams()
    gen = noise.NoiseGenerator(det, params, rng=1, threads=threads)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "noise.fits")
        wall, cpu, _ = _timed(lambda: noise.write_noise_fits(path, gen, frames,
                                                             unit="DN", gain=1.0))
        nbytes = os.path.getsize(path)
    nn, npo = floor_counts(det, params, frames)
    return dict(wall=wall, cpu=cpu, n_normal=nn, n_poisson=npo, lam=0.0,
                n_pink=pink_samples(det, params, frames), output_bytes=nbytes,
                detail=f"H2RG 2048x2048, 4 outputs, {frames} frames, NG defaults, "
                       f"uint16 DN to FITS")


def _run_engine(det, readout, rate, threads, noise_params, *, options=None,
                on_resultant=None):
    """Run a ChargeEngine (to a temp FITS file unless ``on_resultant`` is given: then
    each :class:`scenesim.engine.Resultant` goes to it).

    Returns ``((wall, cpu, output bytes), engine)``."""
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
        wall, cpu, _ = _timed(consume)
        return (wall, cpu, 0), eng
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "exp.fits")
        # as `scenesim run` writes an exposure that no fit reads back
        wall, cpu, _ = _timed(lambda: write_exposure(eng, path, write_behind=True))
        return (wall, cpu, os.path.getsize(path)), eng


def _engine_result(det, readout, rate, params, timing, detail):
    wall, cpu, nbytes = timing
    nints = readout.nints
    n_reads = nints * len(readout.needed_reads)
    charged = int(np.count_nonzero(rate[~det.reference_mask()] > 0))
    nn, npo = floor_counts(det, params, n_reads, nints, charged, n_reads)
    return dict(wall=wall, cpu=cpu, n_normal=nn, n_poisson=npo,
                lam=typical_lambda(rate, det.frame_time), detail=detail,
                n_pink=pink_samples(det, params, n_reads), output_bytes=nbytes,
                pixel_reads=int(det.ny * det.nx * n_reads))


def _star_rates(shape, n, rng, log_flux):
    """Rate map (e-/s) of ``n`` point sources with log10 flux uniform in ``log_flux``."""
    from scenesim.sky.psf import GaussianPSF, render_point_sources
    ny, nx = shape
    x, y = rng.uniform(0, nx - 1, n), rng.uniform(0, ny - 1, n)
    flux = 10 ** rng.uniform(*log_flux, n)
    return render_point_sources(shape, x, y, flux, GaussianPSF(2.0))[0]


def bench_jwst(size, threads):
    """H2RG star field: 1000 stars over 4 decades, RAPID, full noise."""
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
                             else "whole exposure written (no fit: written behind)"))


def roman_scene(size):
    """Detector, readout and rate map (e-/s, float64 (ny, nx)) of the Roman workload.

    ``size`` ``'full'``: H4RG-10 4096x4096; otherwise a 1024x1024 corner.  Readout:
    :data:`scenesim.detector.readout.ROMAN_LIKE_TABLE` (9 resultants, 44 reads).
    Rates: 1 e-/s everywhere, 0.5 % of the pixels at 100-1000 e-/s (seed 4); the
    reference border collects no charge in the engine.
    """
    from scenesim.detector.readout import ROMAN_LIKE_TABLE, Readout
    quick = size != "full"
    det = noise.preset("H4RG-10", naxis1=1024, naxis2=1024) if quick \
        else noise.preset("H4RG-10")
    ro = Readout.from_ma_table(ROMAN_LIKE_TABLE)
    g = np.random.default_rng(4)
    rate = np.ones(det.shape)
    bright = g.random(det.shape) < 0.005
    rate[bright] = g.uniform(100, 1000, int(bright.sum()))
    return det, ro, rate


def bench_roman(size, threads):
    """H4RG-10 with a 9-resultant / 44-read MA table, 0.5 % bright pixels, full noise."""
    det, ro, rate = roman_scene(size)
    params = noise.NoiseParams()
    timing, _ = _run_engine(det, ro, rate, threads, params)
    return _engine_result(det, ro, rate, params, timing,
                          f"H4RG-10 {det.ny}x{det.nx}, 9 resultants / 44 reads, bg 1 "
                          f"e-/s + 0.5% at 100-1000 e-/s, full noise")


def bench_timeseries(nints, threads):
    """64x64 window, ``nints`` integrations of RAPID x 5, one star, full noise."""
    from scenesim.detector.readout import Readout
    from scenesim.sky.psf import GaussianPSF, render_point_sources
    det = noise.preset("H2RG").window(992, 992, 64, 64, name="BENCH64")
    ro = Readout.named("RAPID", 5, nints=nints)
    rate = 0.51 + render_point_sources(det.shape, 31.5, 31.5, 1e4, GaussianPSF(2.0))[0]
    params = noise.NoiseParams()
    timing, _ = _run_engine(det, ro, rate, threads, params)
    return _engine_result(det, ro, rate, params, timing,
                          f"64x64 window, {nints} ints x RAPID 5, 1 star 1e4 e-/s, "
                          f"full noise")


#: Jump threshold (sigma) of the ``gls-jump`` fit case: stcal LIKELY's own default
#: one-omit threshold, sqrt(20.25) (its jump detection cannot be switched off).
FIT_JUMP_SIGMA = 4.5

_FIT_NGROUPS, _FIT_RATE, _FIT_RN = 20, 10.0, 10.0


def fit_input(size):
    """The cube every fit case (and the stcal peer) fits.

    ``size`` x ``size`` pixels, 20 RAPID resultants (one read each, at ``(k + 1)
    t_frame`` of the H2RG preset), 10 e-/s, white read noise 10 e- per read (seed 6).

    Returns
    -------
    cube : ndarray (20, size, size), float32, e-
    meta : dict
        ``t_frame`` (s), ``read_noise`` (e- per read), ``rate`` (e-/s).
    """
    tf = noise.preset("H2RG").frame_time
    g = np.random.default_rng(6)
    cube = np.empty((_FIT_NGROUPS, size, size), dtype=np.float32)
    acc = np.zeros((size, size), dtype=np.float32)
    for k in range(_FIT_NGROUPS):
        acc += g.poisson(_FIT_RATE * tf, (size, size)).astype(np.float32)
        cube[k] = acc + np.float32(_FIT_RN) * g.standard_normal((size, size),
                                                                dtype=np.float32)
    return cube, dict(t_frame=tf, read_noise=_FIT_RN, rate=_FIT_RATE)


#: Array sizes and resultant counts of the fit's scaling cases (full run).
FIT_SCALING_SIZES = (512, 1024, 2048, 4096)
FIT_SCALING_NRES = (5, 10, 20, 50, 100, 200)
#: The same for ``--quick``.
_FIT_SCALING_QUICK = ((128, 256), (5, 20, 50))
#: Bias (DN) of the scaling cases' files: keeps read noise above 0 in uint16.
_FIT_BIAS_DN = 1000.0


def fit_scaling_cases(sizes, nres):
    """The scaling cases ``(size, 'gls', n)`` for every size and resultant count."""
    return [(int(s), "gls", int(n)) for s in sizes for n in nres]


def write_fit_ramp(path, size, nres):
    """Write the exposure file of the fit's scaling cases, one resultant at a time.

    ``size`` x ``size`` pixels, ``nres`` RAPID resultants (one read each at ``(k + 1)
    t_frame``), 10 e-/s Poisson, white read noise 10 e- per read, gain 1, a bias of
    1000 DN, rounded to uint16 DN (seed 6; the first ``n`` resultants are the same
    whatever ``nres``).  Only one frame is in memory at a time.
    """
    from astropy.io import fits
    from scenesim.detector.readout import Readout
    from scenesim.io.header import filetype_card, nextend_card
    tf = noise.preset("H2RG").frame_time
    g = np.random.default_rng(6)
    acc = np.zeros((size, size), dtype=np.float32)
    ro = Readout.named("RAPID", nres)
    cards = [filetype_card("exposure"), nextend_card(2),
             ("GAIN", 1.0, "e-/DN"), ("RDNOISE", _FIT_RN, "e- per read, not CDS"),
             ("TFRAME", tf, "s"), ("NGROUPS", nres, ""), ("NINTS", 1, "")]
    with open(path, "wb") as f:
        s = StreamingFITS(f)
        s.begin_image((), np.uint8, cards)
        s.end_image()
        s.begin_image((1, nres, size, size), np.uint16, name="SCI")
        for _ in range(nres):
            acc += g.poisson(_FIT_RATE * tf, (size, size)).astype(np.float32)
            dn = acc + np.float32(_FIT_BIAS_DN) + np.float32(_FIT_RN) * \
                g.standard_normal((size, size), dtype=np.float32)
            s.write(np.clip(np.rint(dn), 0, 65535).astype(np.uint16))
        s.end_image()
        s.append_hdu(fits.BinTableHDU(ro.read_table(tf), name="READS"))


def prepare_fit(spec, directory, cases=()):
    """Write the input of this fit case to ``directory`` once; return the keyword
    arguments of :func:`bench_fit`.

    ``(size, fitter)``: :func:`fit_input` as ``.npy`` (``cube`` = its path; the slopes
    are saved in ``directory`` too).  ``(size, 'gls', nres)``: the exposure file of
    :func:`write_fit_ramp` holding the longest ramp of that size among ``cases``
    (``cube`` = its path).
    """
    from scenesim.io.cuberows import exposure_rows
    if len(spec) == 3:
        size = spec[0]
        longest = max([c[2] for c in cases if len(c) == 3 and c[0] == size]
                      + [spec[2]])
        path = os.path.join(directory, f"fit_ramp_{size}.fits")
        if not os.path.exists(path) or exposure_rows(path).shape[1] < spec[2]:
            for old in os.listdir(directory):     # one size's file at a time on disk
                if old.startswith("fit_ramp_"):
                    os.unlink(os.path.join(directory, old))
            write_fit_ramp(path, size, longest)
        return dict(cube=path)
    path = os.path.join(directory, f"fit_cube_{spec[0]}.npy")
    if not os.path.exists(path):
        cube, _ = fit_input(spec[0])
        np.save(path, cube)
    return dict(cube=path, out_dir=directory)


def bench_fit(spec, threads, *, cube=None, out_dir=None):
    """Ramp fit of ``size`` x ``size`` x 20 RAPID resultants with one fitter, or a
    scaling case.

    ``spec`` = ``(size, fitter)``, fitter ``'cds'``, ``'ols'``, ``'gls'`` or
    ``'gls-jump'`` (GLS with jump detection at :data:`FIT_JUMP_SIGMA`).  ``cube``: the
    ``.npy`` file of :func:`prepare_fit` (made in memory when None).  ``out_dir``:
    where the slopes and variances are saved (``.npy``, after the timed fit), as the
    stcal peer saves its own.  ``spec`` = ``(size, 'gls', nres)``: a scaling case
    (module notes, :func:`_bench_fit_scaling`); ``cube`` is its exposure file.
    """
    from scenesim.rampfit import fit_ramps
    if len(spec) == 3:
        return _bench_fit_scaling(spec, threads, cube)
    size, fitter = spec
    _, meta = fit_input(0)
    tf, rn = meta["t_frame"], meta["read_noise"]
    data = np.load(cube) if cube is not None else fit_input(size)[0]
    ngroups = data.shape[0]
    times = [np.array([(k + 1) * tf]) for k in range(ngroups)]
    t0 = time.perf_counter()
    data.sum(dtype=np.float64)
    baseline = time.perf_counter() - t0
    name, thr = (("gls", FIT_JUMP_SIGMA) if fitter == "gls-jump" else (fitter, None))
    wall, cpu, res = _timed(lambda: fit_ramps(data, times, read_noise=rn, fitter=name,
                                              jump_threshold=thr, threads=threads))
    slope = np.asarray(res.slope, dtype=np.float64)
    if out_dir is not None:
        np.save(os.path.join(out_dir, "slope.npy"), np.asarray(res.slope, np.float32))
        np.save(os.path.join(out_dir, "var.npy"), np.asarray(res.var, np.float32))
    return dict(wall=wall, cpu=cpu, baseline=baseline,
                baseline_kind="memory bandwidth: one np.sum over the cube",
                detail=f"{size}x{size}x{ngroups}, 10 e-/s, 10 e- per read, {fitter}"
                       + (f" ({FIT_JUMP_SIGMA} sigma)" if thr else ""),
                median_slope=float(np.nanmedian(slope)))


def _bench_fit_scaling(spec, threads, path):
    """GLS fit of the first ``nres`` resultants of ``path`` read by row blocks.

    Also times, in this process and on the fit's own row blocks: one read of the cube
    (``read_pass``: file to float32 e-) and ``np.sum`` over each block read
    (``baseline``: the memory-bandwidth time of the cube's float32 values).
    """
    from scenesim.io.cuberows import exposure_rows
    from scenesim.rampfit import fit_ramps
    from scenesim.rampfit.solver import row_chunks
    size, fitter, nres = spec
    if path is None:
        raise ParameterError("the fit's scaling cases need their exposure file "
                             "(prepare_fit)")
    src = exposure_rows(path, nres=nres)
    tf = noise.preset("H2RG").frame_time
    times = [np.array([(k + 1) * tf]) for k in range(nres)]
    bounds = row_chunks(size, size, nres, threads=threads)   # the fit's own blocks
    t_read = t_sum = 0.0
    for y0, y1 in bounds:
        t0 = time.perf_counter()
        blk = src.rows(y0, y1)
        t1 = time.perf_counter()
        blk.sum(dtype=np.float64)
        t_sum += time.perf_counter() - t1
        t_read += t1 - t0
    del blk
    rss_before = peak_rss_self()
    wall, cpu, res = _timed(lambda: fit_ramps(src, times, read_noise=_FIT_RN,
                                              fitter=fitter, threads=threads))
    return dict(wall=wall, cpu=cpu, baseline=t_sum, read_pass=t_read,
                baseline_kind="memory bandwidth: np.sum over each row block of the "
                              "float32 cube",
                nres=nres, size=size, blocks=len(bounds),
                cube_mb=nres * size * size * 4 / 2 ** 20,
                file_mb=os.path.getsize(path) / 2 ** 20,
                rss_before_fit_mb=rss_before,
                detail=f"{size}x{size}x{nres} RAPID, 10 e-/s, 10 e- per read, "
                       f"{fitter}, read by {len(bounds)} row blocks from a uint16 "
                       f"exposure file",
                median_slope=float(np.median(np.asarray(res.slope, np.float64))))


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


#: White read noise on a bias 1000 e- (~190 sigma) above the ADC's code 0
WHITE = noise.ZERO_NOISE.replace(rd_noise=5.2, bias_offset=1000.0)


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
    from scenesim.detector.readout import Readout
    what, defeated = case
    det = noise.preset("H2RG")
    ro = Readout.named("RAPID", 5)
    params = noise.ZERO_NOISE
    rate = np.zeros(det.shape)
    keep = None
    if what == "zero_amplitude":
        params = WHITE
        if defeated:
            params = params.replace(c_pink=1e-12, u_pink=1e-12, acn=1e-12, pca0=1e-12,
                                    pedestal=1e-12)
    elif what == "no_charge":
        rate = _star_rates(det.shape, 100, np.random.default_rng(5), (2, 4))
        rate[rate < 1e-3] = 0.0
        if defeated:
            rate = rate + 1e-12
    elif what == "unused_frames":
        params = WHITE
        rate = np.full(det.shape, 1.0)
        ro = Readout.named("DEEP8", 2)
        if defeated:
            ro = Readout.from_reads([list(range(g * 20, g * 20 + 20)) for g in range(2)])
    elif what == "no_ramp_file":
        params = WHITE
        rate = np.full(det.shape, 1.0)
        if not defeated:
            keep = lambda res: None  # noqa: E731  (in-memory resultants, no file)
    else:
        raise ParameterError(f"unknown skip case {what!r}")
    timing, _ = _run_engine(det, ro, rate, threads, params, on_resultant=keep)
    return _engine_result(det, ro, rate, params, timing,
                          f"{what}: {'skip defeated' if defeated else 'skipped'}")


def _bench_batch(case, threads, **kwargs):
    """:func:`scenesim.batch.bench.bench_batch` (imported when it runs: dask)."""
    from scenesim.batch.bench import bench_batch
    return bench_batch(case, threads, **kwargs)


#: Workload name -> (function, full cases, quick cases).
WORKLOADS = {
    "noise": (bench_noise, [10, 40, 88], [1, 5]),
    "jwst": (bench_jwst, ["full", "full-engine"], ["quick", "quick-engine"]),
    "roman": (bench_roman, ["full"], ["quick"]),
    "fit": (bench_fit, [(2048, f) for f in ("cds", "ols", "gls", "gls-jump")]
            + fit_scaling_cases(FIT_SCALING_SIZES, FIT_SCALING_NRES),
            [(512, f) for f in ("cds", "ols", "gls", "gls-jump")]
            + fit_scaling_cases(*_FIT_SCALING_QUICK)),
    "timeseries": (bench_timeseries, [300], [30]),
    "options": (bench_options, [(c, "full") for c in OPTION_CASES],
                [(c, "quick") for c in OPTION_CASES]),
    "pink": (bench_pink, [10], [2]),
    "skips": (bench_skips, [(w, d) for w in ("zero_amplitude", "no_charge",
                                              "unused_frames", "no_ramp_file")
                            for d in (False, True)],
              [("zero_amplitude", False), ("zero_amplitude", True)]),
    # exposures per minute on dask (1 and 2 workers) against a loop of runs
    "batch": (_bench_batch, [24], [4]),
}

#: Workload name -> function(case, directory, cases) that writes the case's input to
#: ``directory`` (once; ``cases``: all the run's cases of that workload) and returns
#: extra keyword arguments of the workload.
PREPARE = {"fit": prepare_fit}
