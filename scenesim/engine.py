"""The charge engine: Poisson arrivals at each pixel's own read time, read by read.

Physics (DESIGN.md sections 2 and 5)
------------------------------------
Pixel ``p`` of integration ``i`` is read at absolute times ``s * t_frame + t_pix(p)``
for the frame slots ``s`` of the needed reads (``noise.Detector.pixel_time`` gives
``t_pix``).  Between two consecutive needed reads (or the reset and the first read)
the charge collected is an independent Poisson draw with mean
``integral rate_p(t) dt`` over that pixel's own interval: ``rate * dt`` for constant
rates (dark current, background, static sources) plus, for sources with a light curve,
the stamp weight times the light curve's exact integral over the interval.  Charge is
accumulated as integers; pixels whose rate is 0 draw nothing, reads no resultant uses
are never materialised (their charge is part of the next needed interval).

Reset: *rolling* (default) resets each pixel one frame time before its first read;
*global* resets all pixels at the start of the first read frame, so the first read's
integration time is ``k * t_frame + t_pix(p)``.

Cosmic rays deposit charge at a time ``T``: a pixel sees it in the first of its reads
whose time is after ``T``; a hit before the pixel's reset is erased by the reset.

The rates are those of the charge collected: a quantum-efficiency flat has already
scaled the light in them (:func:`scenesim.sky.rates.scene_rates`), so the arrivals
stay Poisson.  After the charge of each read is known, effects apply in physical
order, each through its one implementation in :mod:`scenesim.detector`: (1)
saturation at the full well (:class:`~scenesim.detector.saturation.FullWell`), (2)
polynomial nonlinearity (:class:`~scenesim.detector.nonlinearity.Nonlinearity`), (3)
IPC (:func:`~scenesim.detector.ipc.apply_ipc`), then (4) the noise frame from
:mod:`noise` (bias, kTC, pedestal, 1/f, ACN, white) is added, and (5) the ADC
(:class:`noise.adc.ADC`) turns electrons into DN through the gain, rounding and
clipping to the top code.
Reads are digitised one by one and averaged into resultants (rounded), like on-board
frame averaging.  Only a few frames are held in memory; finished resultants are
written straight to the output file.

Poisson draws use :func:`noise.fast.poisson.poisson` (exact inversion for means up to
10 e-, numpy's sampler above; 1.4-3x faster than numpy's at the small means of
dark current and background).

Randomness and draw layout: one root ``SeedSequence``; the streams are those of the
registry :mod:`noise.streams` (the noise generator ``NOISE``, Poisson arrivals
``POISSON``, the '2d' shortcut ``POISSON_2D``).  The frame is cut into stream chunks
of ``max(32, ceil(65536 / nx))`` rows (32 rows for nx >= 2048, one chunk for a 64x64 window); chunk ``c`` (counted
from row 0) of integration ``i`` draws every Poisson variate of that integration from
one generator with spawn key ``POISSON + (i, c)`` (the '2d' shortcut:
``POISSON_2D + (i, c)``), in read order.  A chunk at least half charged draws every
pixel (mean 0, hence exactly 0 e-, where nothing is collected: no gather/scatter per read); a sparser chunk draws
only its charged pixels.  The reads of an integration are drawn in groups of
``max(1, 65536 // n)`` reads per call, ``n`` the most pixels any chunk draws (a 64x64
window draws its 5 RAPID reads in one call; 2048^2 and 4096^2 frames one read per
call), which removes the per-read Python overhead of small frames.  Chunks, groups
and keys depend only on the detector, the readout and the rate map, never on the
thread count or on the row blocks of the per-read passes, so neither changes the
result.  The rate map does change them: which pixels a chunk draws, and the group
size (from the chunk that draws the most), so adding a source, even in another
chunk, redraws the Poisson arrivals of the others (a probe's far star changed 1640
samples of another's stamp); the noise, hot pixels and cosmic rays, on their own
streams, are unchanged.  Paired runs that must share the arrivals of the common
sources need the same rate map.
"""

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from noise.validate import (check_bool, check_choice, check_float, check_instance,
                            check_int, check_map, describe, is_sequence)
from noise.errors import ParameterError, ParameterTypeError
from noise import streams
from noise.adc import ADC
from noise.clock import Detector, exposure_slots, frame_slot
from noise.generator import NoiseGenerator
from noise.params import NoiseParams
from noise.streams import root_seed

from noise.fast.poisson import poisson
from scenesim.detector.ipc import apply_ipc, check_kernel
from scenesim.detector.nonlinearity import Nonlinearity
from scenesim.detector.readout import Readout, check_pattern_detector, read_index_dtype
from scenesim.detector.saturation import FullWell

__all__ = ["VariableSource", "CosmicRayHits", "EngineOptions", "ChargeEngine",
           "ARRIVALS", "MAX_CHARGE"]

#: Most charge a pixel may collect in one integration, e-: 2**53 = 9.0e15, the largest
#: count float64 (the Poisson means, the saved charge) holds exactly; the int64
#: accumulator and numpy's Poisson sampler (9.2e18) are beyond it.
MAX_CHARGE = 2.0 ** 53

# Poisson stream layout (fixed by the detector and readout, never by the threads):
_ROWS = 32               # at least this many rows per stream chunk ...
_CHUNK_PIXELS = 65536    # ... and at least this many pixels (one chunk below it)
_DENSE = 0.5             # chunks at least this charged are drawn whole (0 e- elsewhere)
_GROUP_DRAWS = 65536     # reads drawn per call: max(1, _GROUP_DRAWS // chunk draws)
_RUNS_PER_THREAD = 4     # pool tasks per thread and read: runs of consecutive chunks
ARRIVALS = ("time", "2d")


@dataclass(frozen=True, eq=False)
class VariableSource:
    """A source whose flux follows a light curve.

    Parameters
    ----------
    index : ndarray of int
        Flat pixel indices of its stamp on the read-out image.
    weight : ndarray of float
        Rate at relative flux 1 in each stamp pixel, e-/s.
    light_curve : scenesim.sky.lightcurve.LightCurve
        Relative flux versus time (s from the start of the exposure).
    """

    index: np.ndarray
    weight: np.ndarray
    light_curve: object


@dataclass(frozen=True, eq=False)
class CosmicRayHits:
    """Charge deposits: absolute time (s from exposure start), flat pixel index, e-."""

    time: np.ndarray
    index: np.ndarray
    charge: np.ndarray

    @classmethod
    def empty(cls):
        return cls(np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros(0))


@dataclass(frozen=True)
class EngineOptions:
    """Explicit approximations (the exact path is the default).

    Parameters
    ----------
    gauss_above : float or None
        Draw ``N(lambda, lambda)`` rounded to integers instead of Poisson where the
        mean per interval exceeds this (e-).  ``None``: always Poisson (exact).
    shot_noise : bool
        ``False`` accumulates the expected charge (float, no Poisson draws): a
        noise-free reference ramp for validating fitters and files.
    arrivals : {'time', '2d'}
        ``'time'`` (exact): an independent Poisson draw per pixel and read interval.
        ``'2d'``: the paper's fast shortcut (Rauscher 2015, section 6): one Poisson
        image of the charge expected at the last needed read of each integration,
        spread over the reads in proportion to the expected charge.  It draws one
        variate per pixel per integration instead of one per read, keeps the right
        final charge and mean ramp, but the ramp has no shot noise from read to read
        (its increments are perfectly correlated), so the fitted slope scatter and
        the jump statistics are wrong at high flux; ``scenesim bench options``
        measures by how much.  Cosmic rays are unaffected.
    threads : int or None
        Worker threads (default: all cores).  Results do not depend on it.
    """

    gauss_above: float | None = None
    shot_noise: bool = True
    arrivals: str = "time"
    threads: int | None = None

    def __post_init__(self):
        check_choice("arrivals", self.arrivals, ARRIVALS)
        check_bool("shot_noise", self.shot_noise)
        if self.gauss_above is not None:
            check_float("gauss_above", self.gauss_above, minimum=0.0)
        if self.threads is not None:
            check_int("threads", self.threads, minimum=1)


@dataclass
class _Resultant:
    reads: tuple
    dn_sum: np.ndarray = None
    charge_sum: np.ndarray = None
    noise_sum: np.ndarray = None
    raw_sum: np.ndarray = None
    count: int = 0


@dataclass(frozen=True, eq=False)
class Resultant:
    """One finished resultant of a run.

    Attributes
    ----------
    integration, index : int
        Integration and resultant (0-based).
    dn : ndarray (ny, nx), uint16, DN
        The resultant as read out (the rounded mean of its digitised reads).
    charge, noise : ndarray (ny, nx), float32, e-, or None
        Noise-free signal (the charge after saturation, nonlinearity and IPC) and
        noise-only part, when the run was asked for them.
    raw_ref : ndarray (ny, n), uint16, DN, or None
        On a detector with interleaved reference samples or a reference output
        (``Detector.has_raw_samples``): those samples, digitised and averaged as the
        pixels are, in the order of the raw columns that hold them
        (``Detector.raw_columns``, ``image_x < 0``); None otherwise.
    """

    integration: int
    index: int
    dn: np.ndarray
    charge: np.ndarray | None = None
    noise: np.ndarray | None = None
    raw_ref: np.ndarray | None = None


class EngineRun:
    """A run of a :class:`ChargeEngine` (:meth:`ChargeEngine.simulate`): an iterator
    of :class:`Resultant` in time order.

    Attributes
    ----------
    sat_read : ndarray (nints, ny, nx), int16 (int32 beyond 32767 reads)
        First saturated read index (-1: never): the first read whose charge reached
        the full well, or whose charge and noise read the ADC's top code (the ADC
        clips it as surely); complete when the run is exhausted.
    cr_seen : ndarray of bool
        Per cosmic-ray deposit, True if any read saw it; complete at the end.
    zero_frame : ndarray (nints, ny, nx), uint16, or None
        With ``simulate(zero_frame=True)``: the DN of the first read of each
        integration's first resultant, digitised on its own (JWST's ``ZEROFRAME``);
        complete at the end.
    """

    def __init__(self, engine, *, save_charge, save_noise, progress, zero_frame=False):
        shape = engine.detector.shape
        self.sat_read = np.full((engine.readout.nints,) + shape, -1,
                                dtype=read_index_dtype(engine.readout.nreads))
        self.zero_frame = (np.zeros((engine.readout.nints,) + shape, dtype=np.uint16)
                           if zero_frame else None)
        self.cr_seen = np.zeros(engine.cosmic_rays.time.size, dtype=bool)
        self.pool = ThreadPoolExecutor(engine.threads) if engine.threads > 1 else None
        self.blocks = engine._blocks()
        self.finalizers = []
        self._gen = engine._reads(self, save_charge, save_noise, progress)

    def each(self, fn):
        """``fn(rows)`` for every row block (on the pool when there are several)."""
        if self.pool is not None and len(self.blocks) > 1:
            list(self.pool.map(fn, self.blocks))
        else:
            for b in self.blocks:
                fn(b)

    def __iter__(self):
        return self

    def __next__(self):
        try:
            return next(self._gen)
        except BaseException:
            self.close()
            raise

    def close(self):
        """Stop the run (if not finished) and release its threads and noise stream."""
        self._gen.close()
        while self.finalizers:
            self.finalizers.pop()()
        if self.pool is not None:
            self.pool.shutdown()
            self.pool = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


class ChargeEngine:
    """Simulate the resultants of one exposure, streaming them to callbacks.

    Parameters
    ----------
    detector : noise.Detector
    readout : scenesim.detector.readout.Readout
    noise_params : noise.NoiseParams or None
        ``None`` (or all amplitudes 0) adds no noise.
    rate : float or ndarray (ny, nx)
        Constant rate, e-/s (dark + background + static sources).  Reference pixels
        are forced to 0 (they collect no charge).
    variable_sources : sequence of VariableSource
    cosmic_rays : CosmicRayHits or None
    full_well : float, ndarray (ny, nx) or None
        Saturation level, e-.
    nonlinearity : scenesim.detector.nonlinearity.Nonlinearity or None
    ipc_kernel : ndarray (3, 3) or None
    gain : float
        e-/DN.
    adc_bits : int
        ADC resolution, 1 to 16 (resultants are stored as uint16).
    rng : int, SeedSequence, Generator or None
    options : EngineOptions
    """

    def __init__(self, detector, readout, *, noise_params=None, rate=0.0,
                 variable_sources=(), cosmic_rays=None, full_well=None,
                 nonlinearity=None, ipc_kernel=None, gain=1.0, adc_bits=16,
                 rng=None, options=EngineOptions()):
        self.detector = check_instance("detector", detector, Detector, "a noise.Detector")
        self.readout = check_instance("readout", readout, Readout,
                                      "a scenesim.detector.readout.Readout")
        # the files name the pattern (READPATT): an IRS2 name needs an IRS2 detector
        check_pattern_detector(self.readout.name, self.detector)
        check_instance("noise_params", noise_params, NoiseParams, "a noise.NoiseParams",
                       allow_none=True)
        check_instance("nonlinearity", nonlinearity, Nonlinearity,
                       "a scenesim.detector.nonlinearity.Nonlinearity", allow_none=True)
        check_instance("options", options, EngineOptions, "a scenesim.engine.EngineOptions")
        check_instance("cosmic_rays", cosmic_rays, CosmicRayHits,
                       "a scenesim.engine.CosmicRayHits", allow_none=True)
        if isinstance(variable_sources, (str, bytes, dict, np.ndarray)) or \
                not is_sequence(variable_sources):
            raise ParameterTypeError(
                f"'variable_sources' must be a sequence of VariableSource, got "
                f"{describe(variable_sources)}")
        for v in variable_sources:
            check_instance("variable_sources", v, VariableSource,
                           "a sequence of scenesim.engine.VariableSource")
        shape = detector.shape
        self.refmask = detector.reference_mask()
        # reference pixels collect no charge
        self.rate = np.array(np.broadcast_to(check_map("rate", rate, shape), shape))
        self.rate[self.refmask] = 0.0
        self.variable = [self._check_variable(v) for v in variable_sources]
        cr = self._check_cosmic_rays(cosmic_rays) if cosmic_rays is not None else \
            CosmicRayHits.empty()
        if cr.index.size:
            keep = ~self.refmask.reshape(-1)[cr.index]
            cr = CosmicRayHits(cr.time[keep], cr.index[keep], cr.charge[keep])
        self.cosmic_rays = cr
        self.gain = check_float("gain", gain, minimum=0.0, strict_min=True)
        # resultants are stored as uint16: at most 16 bits
        self.adc_bits = check_int("adc_bits", adc_bits, minimum=1, maximum=16)
        self.adc = ADC(self.gain, self.adc_bits)
        if noise_params is not None:
            # no noise clipped at the ADC (noise.params module notes)
            noise_params.check_adc(self.gain, self.adc_bits, detector)
            noise_params.warn_quantisation(self.gain, "[effects] 'gain'")
        self.full_well = None if full_well is None else FullWell(full_well, shape)
        self.nonlinearity = nonlinearity if (nonlinearity is not None
                                             and not nonlinearity.is_linear) else None
        self.ipc_kernel = None
        if ipc_kernel is not None:
            check_kernel(ipc_kernel)                 # refused here, before any work
            self.ipc_kernel = np.asarray(ipc_kernel, dtype=float)
        self.options = options
        self.entropy, self.key = root_seed(rng)
        threads = options.threads if options.threads is not None else (os.cpu_count() or 1)
        self.threads = max(1, int(threads))
        self.noise = None
        if noise_params is not None and not noise_params.is_silent():
            self.noise = NoiseGenerator(
                detector, noise_params, threads=self.threads,
                rng=np.random.SeedSequence(self.entropy, spawn_key=self.key + streams.NOISE))
        self._plan_chunks()
        # per-integration invariants of the light-curve sources and cosmic rays
        self._var_tpix = [self._pixel_time_flat(v.index) for v in self.variable]
        if self.variable:
            self._var_uniq, self._var_inv = np.unique(
                np.concatenate([v.index for v in self.variable]), return_inverse=True)
        self._cr_tpix = self._pixel_time_flat(self.cosmic_rays.index)
        self._check_charge()
        self._dtype = np.int64 if self._max_charge() > 2e9 else np.int32
        if not options.shot_noise or options.arrivals == "2d":
            self._dtype = np.float64
        self._scale = None        # per-pixel N / lambda_total of the '2d' shortcut
        self._gens = None         # per-chunk Poisson generators of the integration
        self._drawn = None        # per-chunk draws of the current group of reads

    @property
    def poisson_layout(self):
        """The layout of the Poisson streams (module notes), fixed by the detector, the
        readout and the rates, never by the threads.

        Returns
        -------
        dict
            ``chunks``: one ``(row0, row1, sparse)`` per stream chunk with charge
            (``sparse``: only its charged pixels are drawn); ``reads_per_call``: reads
            drawn at once per chunk; ``charged_pixels``: pixels with a rate or a
            light-curve source.
        """
        return {"chunks": [(c0, c1, idx is not None) for c0, c1, idx in self._chunks],
                "reads_per_call": self._group, "charged_pixels": self._npix_charged}

    def _plan_chunks(self):
        """The Poisson stream chunks: row ranges fixed by the detector; a chunk draws
        every pixel (lambda = 0 where there is no charge) when most of it has charge,
        else only its pixels with charge (``idx``: flat indices within the chunk)."""
        det = self.detector
        has = self.rate > 0
        for v in self.variable:
            has.ravel()[v.index] = True
        self._has_charge = bool(has.any()) or self.cosmic_rays.time.size > 0
        self._npix_charged = int(np.count_nonzero(has))
        self._chunk_rows = max(_ROWS, -(-_CHUNK_PIXELS // det.nx))
        self._chunks, self._chunk_rate = [], []
        for c0 in range(0, det.ny, self._chunk_rows):
            c1 = min(c0 + self._chunk_rows, det.ny)
            sub = has[c0:c1].reshape(-1)
            n = int(np.count_nonzero(sub))
            if n == 0:
                continue
            idx = None if n >= _DENSE * sub.size else np.flatnonzero(sub)
            flat_rate = self.rate[c0:c1].reshape(-1)
            self._chunks.append((c0, c1, idx))
            self._chunk_rate.append(flat_rate if idx is None else flat_rate[idx])
        sizes = [r.size for r in self._chunk_rate]
        # reads drawn at once per chunk (fewer calls for small frames; fixed layout)
        self._group = max(1, _GROUP_DRAWS // max(sizes)) if sizes else 1

    # ----------------------------------------------------------------- checks
    def _check_variable(self, v):
        n = self.detector.ny * self.detector.nx
        idx = _as_1d("variable_sources index", v.index, np.int64)
        w = _as_1d("variable_sources weight", v.weight, np.float64)
        if idx.shape != w.shape or (idx.size and (idx.min() < 0 or idx.max() >= n)):
            raise ParameterError(
                f"'variable_sources' stamp indices are out of range: they must be flat "
                f"pixel indices in [0, {n - 1}] with one weight each, got {idx.size} "
                f"indices (range "
                f"{idx.min() if idx.size else '-'}..{idx.max() if idx.size else '-'}) "
                f"and {w.size} weights")
        if not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ParameterError(
                "'variable_sources' weights must be finite and >= 0 e-/s")
        if not callable(getattr(v.light_curve, "integral", None)) or \
                not hasattr(v.light_curve, "flux"):
            raise ParameterTypeError(
                f"'variable_sources' light_curve must be a "
                f"scenesim.sky.lightcurve.LightCurve, got {describe(v.light_curve)}")
        keep = ~self.refmask.ravel()[idx]
        return VariableSource(idx[keep], w[keep], v.light_curve)

    def _check_cosmic_rays(self, cr):
        """The deposits of ``cr`` as 1-D arrays of one length (time s, flat pixel
        index, charge e-): finite, indices on the image, charges in [0, MAX_CHARGE]."""
        n = self.detector.ny * self.detector.nx
        t = _as_1d("cosmic_rays time", cr.time, np.float64)
        raw = np.asarray(cr.index)
        if raw.dtype.kind == "f" and raw.size and not np.all(raw == np.floor(raw)):
            raise ParameterError(          # (truncated to an integer pixel before)
                f"'cosmic_rays index' must be integer flat pixel indices, got "
                f"{describe(cr.index)}")
        idx = _as_1d("cosmic_rays index", cr.index, np.int64)
        q = _as_1d("cosmic_rays charge", cr.charge, np.float64)
        if not t.size == idx.size == q.size:
            raise ParameterError(
                f"'cosmic_rays' needs one time, index and charge per deposit, got "
                f"{t.size}, {idx.size} and {q.size}")
        if idx.size and (idx.min() < 0 or idx.max() >= n):
            raise ParameterError(
                f"'cosmic_rays' indices must be flat pixel indices in [0, {n - 1}], got "
                f"{idx.min()}..{idx.max()}")
        if not np.all(np.isfinite(t)) or not np.all(np.isfinite(q)) or np.any(q < 0) \
                or np.any(q > MAX_CHARGE):
            raise ParameterError(
                f"'cosmic_rays' times must be finite and charges in [0, {MAX_CHARGE:.3g}] "
                f"e-")
        if t is cr.time and idx is cr.index and q is cr.charge:
            return cr
        return CosmicRayHits(t, idx, q)

    def _check_charge(self):
        """Refuse rates whose brightest pixel would collect more than
        :data:`MAX_CHARGE` in one integration, naming the pixel (and the variable
        sources only when they add charge there)."""
        t_int = exposure_slots(1, self.readout.nreads) * self.detector.frame_time
        peak = float(self.rate.max()) if self.rate.size else 0.0
        for v in self.variable:
            if v.weight.size:
                peak += float(v.weight.max()) * float(np.max(v.light_curve.flux))
        if peak * t_int <= MAX_CHARGE:        # a bound: the check below is exact
            return
        # the brightest pixel, the variable sources at their light curves' peak (a
        # scene's run names the file, row or key first: scenesim.sky.rates)
        extra = np.zeros(self.rate.size)
        with np.errstate(over="ignore", invalid="ignore"):
            for v in self.variable:
                np.add.at(extra, v.index, v.weight * float(np.max(v.light_curve.flux)))
            total = self.rate.ravel() + extra
            p = int(np.argmax(total))
            top = float(total[p])
            if top * t_int <= MAX_CHARGE:
                return
        y, x = divmod(p, self.detector.nx)
        parts = f"'rate' is {float(self.rate.ravel()[p]):.3g} e-/s"
        if extra[p] > 0:
            parts += (f" and 'variable_sources' add {float(extra[p]):.3g} e-/s at their "
                      f"light curves' peak")
        raise ParameterError(
            f"{parts} at pixel (x, y) = ({x}, {y}), which would collect "
            f"{top * t_int:.3g} e- over an integration of {t_int:.6g} s; at most "
            f"{MAX_CHARGE:.3g} e- (2**53) per pixel is allowed")

    def _max_charge(self):
        t_total = exposure_slots(1, self.readout.nreads) * self.detector.frame_time
        peak = float(self.rate.max()) if self.rate.size else 0.0
        for v in self.variable:
            if v.weight.size:
                peak += float(v.weight.max()) * float(np.max(v.light_curve.flux))
        return peak * t_total * 1.5 + float(np.sum(self.cosmic_rays.charge))

    # ------------------------------------------------------------------ times
    def read_slot(self, integration, read):
        """Absolute frame slot of ``read`` of ``integration``."""
        return frame_slot(integration, read, self.readout.nreads)

    def _times(self, integration, prev_read, read, tpix):
        """Interval ``(t_prev, t_now]`` (absolute s) of pixels with clock offsets ``tpix``."""
        tf = self.detector.frame_time
        slot = self.read_slot(integration, read)
        t_now = slot * tf + tpix
        if prev_read is not None:
            t_prev = t_now - tf * (read - prev_read)
        elif self.readout.reset_mode == "global":
            t_prev = np.full_like(t_now, (slot - read) * tf)
        else:
            t_prev = t_now - tf * (read + 1)
        return t_prev, t_now

    def _pixel_time_flat(self, index):
        """Clock offset (s) of the pixels at flat ``index`` (no full-frame float array)."""
        return self.detector.pixel_sample_index().reshape(-1)[index] * self.detector.dt

    def _dt(self, prev_read, read, c):
        """Interval length (s) of the drawn pixels of chunk ``c``: a scalar unless the
        first read of a global reset (then ``read * t_frame + t_pix``, per pixel)."""
        tf = self.detector.frame_time
        if prev_read is not None:
            return tf * (read - prev_read)
        if self.readout.reset_mode == "global":
            c0, c1, idx = self._chunks[c]
            t = self.detector.pixel_sample_index()[c0:c1].reshape(-1)
            return read * tf + (t if idx is None else t[idx]) * self.detector.dt
        return tf * (read + 1)

    def _variable_means(self, integration, prev_read, read):
        """Sorted flat indices and expected charge (e-) of light-curve sources."""
        if not self.variable:
            return None
        val = np.concatenate([
            v.weight * v.light_curve.integral(*self._times(integration, prev_read, read, t))
            for v, t in zip(self.variable, self._var_tpix)])
        return self._var_uniq, np.bincount(self._var_inv, weights=val,
                                           minlength=self._var_uniq.size)

    # ---------------------------------------------------------------- charge
    def _lam(self, c, prev_read, read, extra, out=None):
        """Expected charge (e-) of the drawn pixels of chunk ``c`` in one read interval.

        Returns a flat float64 array over the chunk's drawn pixels (``out`` if given).
        """
        c0, c1, idx = self._chunks[c]
        lam = np.multiply(self._chunk_rate[c], self._dt(prev_read, read, c), out=out)
        if extra is not None:
            nx = self.detector.nx
            lo, hi = np.searchsorted(extra[0], [c0 * nx, c1 * nx])
            if hi > lo:
                pos = extra[0][lo:hi] - c0 * nx
                if idx is not None:
                    pos = np.searchsorted(idx, pos)   # every stamp pixel is drawn
                lam[pos] += extra[1][lo:hi]
        return lam

    def _map_chunks(self, task, pool):
        """``task(c)`` for every chunk index (on the pool for large frames, as a few
        runs of consecutive chunks per thread: one dispatch per chunk cost the pool's
        hand-overs; the chunks' results do not depend on the runs)."""
        n = len(self._chunks)
        if pool is not None and n > 1 and self._npix_charged > 65536:
            runs = _even_runs(n, min(n, _RUNS_PER_THREAD * self.threads))
            list(pool.map(lambda run: [task(c) for c in run], runs))
        else:
            for c in range(n):
                task(c)

    def _chunk_generator(self, component, integration, c):
        """The generator of chunk ``c``: spawn key ``(component, integration, chunk)``."""
        return streams.generator(self.entropy, self.key + component + (
            integration, self._chunks[c][0] // self._chunk_rows))

    def _shot_2d(self, integration, needed, pool):
        """'2d' shortcut: per-pixel N / lambda_total for one integration (flat, float64)."""
        scale = np.zeros(self.detector.ny * self.detector.nx)
        nx = self.detector.nx
        extras, prev = [], None
        for k in needed:
            extras.append((prev, k, self._variable_means(integration, prev, k)))
            prev = k

        def task(c):
            c0, c1, idx = self._chunks[c]
            tot = sum(self._lam(c, p, k, e) for p, k, e in extras)
            n = poisson(self._chunk_generator(streams.POISSON_2D, integration, c), tot)
            s = np.divide(n, tot, out=np.zeros_like(tot), where=tot > 0)
            tgt = scale[c0 * nx:c1 * nx]
            if idx is None:
                tgt[:] = s
            else:
                tgt[idx] = s

        self._map_chunks(task, pool)
        return scale

    def _poisson(self, acc, integration, needed, pos, pool):
        """Add the charge of read ``needed[pos]`` (since the previous needed read)."""
        read = needed[pos]
        prev_read = needed[pos - 1] if pos else None
        nx = self.detector.nx
        two_d = self.options.arrivals == "2d"
        draws = self.options.shot_noise and not two_d
        if draws:
            # exact path: the draws of a group of reads at its first read, from the
            # chunk's stream of this integration (consumed in read order)
            j = pos % self._group
            if j == 0:
                group = []
                for q in range(pos, min(pos + self._group, len(needed))):
                    p = needed[q - 1] if q else None
                    group.append((p, needed[q], self._variable_means(integration, p,
                                                                     needed[q])))
        else:
            extra = self._variable_means(integration, prev_read, read)
        gauss = self.options.gauss_above

        def task(c):
            c0, c1, idx = self._chunks[c]
            if draws:
                if j == 0:
                    lam = np.empty((len(group), self._chunk_rate[c].size))
                    for r, (p, k, e) in enumerate(group):
                        self._lam(c, p, k, e, out=lam[r])
                    g = self._gens[c]
                    n = poisson(g, lam) if gauss is None else _poisson_or_gauss(g, lam, gauss)
                    drawn = n.astype(acc.dtype, copy=False)
                    if len(group) > 1:
                        self._drawn[c] = drawn
                else:
                    drawn = self._drawn[c]
                draw = drawn[j]
                if j == len(drawn) - 1:
                    self._drawn[c] = None          # group used up: free it
            else:
                draw = self._lam(c, prev_read, read, extra)
                if two_d:
                    s = self._scale[c0 * nx:c1 * nx]
                    draw *= s if idx is None else s[idx]
            tgt = acc[c0:c1].reshape(-1)
            if idx is None:
                np.add(tgt, draw, out=tgt, casting="unsafe")
            else:
                tgt[idx] += draw.astype(acc.dtype, copy=False)

        self._map_chunks(task, pool)

    def _add_cosmic_rays(self, acc, integration, prev_read, read):
        """Add the deposits whose time falls in each pixel's interval; mask of those."""
        cr = self.cosmic_rays
        if cr.time.size == 0:
            return None
        tp, tn = self._times(integration, prev_read, read, self._cr_tpix)
        hit = (cr.time > tp) & (cr.time <= tn)
        if hit.any():
            np.add.at(acc.reshape(-1), cr.index[hit],
                      np.rint(cr.charge[hit]).astype(acc.dtype))
        return hit

    def _pointwise(self, acc, q, sat_read, integration, read, rows):
        """Effects (1) and (2) on ``rows``: charge ``acc`` -> float32 ``q`` (e-)."""
        qr = q[rows]
        if self.full_well is not None:
            _, sat = self.full_well.apply(acc[rows], rows=rows, out=qr)
            sr = sat_read[integration, rows]
            sr[sat & (sr < 0)] = read
        else:
            np.copyto(qr, acc[rows], casting="unsafe")
        if self.nonlinearity is not None:
            qr[...] = self.nonlinearity.apply(qr)

    def _ipc(self, q):
        """Effect (3), IPC (it couples rows: done on the whole frame)."""
        return apply_ipc(q, self.ipc_kernel, refmask=self.refmask).astype(np.float32,
                                                                         copy=False)

    def _blocks(self):
        """Row blocks of the per-read array passes (results do not depend on them)."""
        ny, nx = self.detector.shape
        # a few blocks per thread, but none below ~64k pixels (dispatch overhead)
        n = max(1, min(ny, 4 * self.threads, -(-ny * nx // 65536)))
        return [slice(r.start, r.stop) for r in _even_runs(ny, n)]

    # ------------------------------------------------------------------- run
    def simulate(self, *, save_charge=False, save_noise=False, progress=None,
                 zero_frame=False):
        """Start a run: the resultants of every integration, in time order.

        Parameters
        ----------
        save_charge, save_noise : bool
            Also give the noise-free signal (the charge after saturation,
            nonlinearity and IPC) and the noise-only part of each resultant (float32
            e-).
        progress : callable, optional
            Called with the number of reads done after each read.
        zero_frame : bool
            Keep the DN of the first read of each integration's first resultant
            (``EngineRun.zero_frame``, one uint16 frame per integration): JWST's
            zero frame, which a group of several reads does not hold otherwise.

        Returns
        -------
        EngineRun
            An iterator of :class:`Resultant`; its ``sat_read`` and ``cr_seen`` are
            complete once it is exhausted.  Close it (or use it as a context
            manager) to stop early: the thread pool and the noise generator are
            released.

        Notes
        -----
        Memory: per read, the engine holds the integer charge ``acc``, one float32
        charge frame, the noise generator's frame, and one exact integer (uint32) DN
        sum per open resultant; everything per pixel is done in row blocks on the
        thread pool (elementwise, so the blocks do not change the result).
        """
        save_charge = check_bool("save_charge", save_charge)
        save_noise = check_bool("save_noise", save_noise)
        zero_frame = check_bool("zero_frame", zero_frame)
        if progress is not None and not callable(progress):
            raise ParameterTypeError(
                f"'progress' must be a callable or None, got {describe(progress)}")
        return EngineRun(self, save_charge=save_charge, save_noise=save_noise,
                         progress=progress, zero_frame=zero_frame)

    def _start_integration(self, i, needed, pool):
        """Per-integration state: the charge ``acc`` and the Poisson streams."""
        if not self._has_charge:
            return None
        acc = np.zeros(self.detector.shape, dtype=self._dtype)
        if self._chunks and self.options.shot_noise:
            if self.options.arrivals == "2d":
                self._scale = self._shot_2d(i, needed, pool)
            else:
                self._gens = [self._chunk_generator(streams.POISSON, i, c)
                              for c in range(len(self._chunks))]
                self._drawn = [None] * len(self._chunks)
        return acc

    def _charge_of_read(self, run, acc, q, i, needed, pos, prev):
        """Collect the charge of read ``needed[pos]`` into ``acc``; the float32 charge
        frame after the effects (``q``, or a new frame with IPC), or ``None`` when
        the effects are applied later, per row block (no IPC)."""
        k = needed[pos]
        if self._chunks:
            self._poisson(acc, i, needed, pos, run.pool)
        hit = self._add_cosmic_rays(acc, i, prev, k)
        if hit is not None:
            run.cr_seen |= hit
        if self.ipc_kernel is None:
            return None
        run.each(lambda b: self._pointwise(acc, q, run.sat_read, i, k, b))
        return self._ipc(q)

    def _digitise(self, b, rr, first, charge, nframe, save_charge, save_noise, sat,
                  read):
        """Rows ``b`` of one read: charge + noise, through the ADC, into the DN sum
        of its resultant ``rr`` (copied for its first read, added after).  A pixel
        with charge whose code is the top one is clipped: its first such ``read``
        goes into ``sat`` (ny, nx) where it has none yet (the noise alone never
        reaches the top: :meth:`noise.NoiseParams.check_adc`)."""
        if charge is not None and nframe is not None:
            f = np.add(charge[b], nframe[b])
        elif charge is not None:
            f = charge[b].copy()
        elif nframe is not None:
            f = nframe[b].copy()
        else:
            f = np.zeros(rr.dn_sum[b].shape, dtype=np.float32)
        codes = self.adc.codes(f)
        if charge is not None and codes.max(initial=0.0) >= self.adc.top:
            sr = sat[b]
            sr[(codes >= self.adc.top) & (sr < 0)] = read
        if first:
            np.copyto(rr.dn_sum[b], codes, casting="unsafe")
        else:
            np.add(rr.dn_sum[b], codes, out=rr.dn_sum[b], casting="unsafe")
        if save_charge and charge is not None:
            rr.charge_sum[b] += charge[b]
        if save_noise and nframe is not None:
            rr.noise_sum[b] += nframe[b]

    def _finish(self, run, i, r_index, rr, save_charge, save_noise):
        """The :class:`Resultant` of a complete DN sum: the rounded mean."""
        if rr.dn_sum.dtype == np.uint16:
            out_dn = rr.dn_sum
        else:
            out_dn = np.empty(self.detector.shape, dtype=np.uint16)
            run.each(lambda b: self.adc.mean_codes(rr.dn_sum[b], rr.count, out=out_dn[b]))
        ch = (rr.charge_sum / rr.count).astype(np.float32) if save_charge else None
        nz = (rr.noise_sum / rr.count).astype(np.float32) if save_noise else None
        raw_ref = None
        if rr.raw_sum is not None:
            raw_ref = np.empty(rr.raw_sum.shape, dtype=np.uint16)
            self.adc.mean_codes(rr.raw_sum, rr.count, out=raw_ref)
        return Resultant(i, r_index, out_dn, ch, nz, raw_ref)

    def _reads(self, run, save_charge, save_noise, progress):
        """Generator behind :class:`EngineRun`: one :class:`Resultant` at a time."""
        shape, ro = self.detector.shape, self.readout
        needed = list(ro.needed_reads)
        read_to_res = {k: r for r, reads in enumerate(ro.resultants) for k in reads}
        noise_iter = None
        raw = self.detector.has_raw_samples
        if raw:
            # the interleaved / reference-output samples: no charge, digitised as
            # the pixels, averaged into their resultants
            n_extra = int((self.detector.raw_columns()[2] < 0).sum())
        if self.noise is not None:
            # the raw frame's parts, image and extra samples, never the raw layout
            noise_iter = self.noise.frames(ro.nreads, needed, nints=ro.nints, reuse=True,
                                           raw="split" if raw else False)
        run.finalizers.append(lambda: noise_iter is not None and noise_iter.close())
        q = np.empty(shape, dtype=np.float32) if self._has_charge else None
        done = 0
        for i in range(ro.nints):
            acc = self._start_integration(i, needed, run.pool)
            prev = None
            res = [_Resultant(tuple(r)) for r in ro.resultants]
            for pos, k in enumerate(needed):
                charge = None
                if self._has_charge:
                    charge = self._charge_of_read(run, acc, q, i, needed, pos, prev)
                    if charge is None:
                        charge = q
                prev = k
                nframe = next(noise_iter)[2] if noise_iter is not None else None
                extra_f = None
                if raw:
                    if nframe is not None:
                        nframe, extra_f = nframe[0], nframe[1].astype(np.float64)
                    else:
                        extra_f = np.zeros((shape[0], n_extra))
                r_index = read_to_res[k]
                rr = res[r_index]
                first = rr.count == 0
                if first:
                    # a one-read resultant is digitised straight into its uint16
                    # output (the same values: the codes are integral, in [0, top])
                    rr.dn_sum = np.empty(shape, dtype=np.uint16 if len(rr.reads) == 1
                                         else np.uint32)
                    if save_charge:
                        rr.charge_sum = np.zeros(shape, dtype=np.float64)
                    if save_noise:
                        rr.noise_sum = np.zeros(shape, dtype=np.float64)
                    if raw:
                        rr.raw_sum = np.zeros(extra_f.shape, dtype=np.uint32)
                if raw:
                    np.add(rr.raw_sum, self.adc.codes(extra_f), out=rr.raw_sum,
                           casting="unsafe")

                def rows(b, charge=charge, nframe=nframe, rr=rr, first=first, k=k):
                    if charge is q and q is not None and self.ipc_kernel is None:
                        self._pointwise(acc, q, run.sat_read, i, k, b)
                    self._digitise(b, rr, first, charge, nframe, save_charge, save_noise,
                                   run.sat_read[i], k)

                run.each(rows)
                if first and r_index == 0 and run.zero_frame is not None:
                    # the first read's codes, copied before the next read adds to them
                    np.copyto(run.zero_frame[i], rr.dn_sum, casting="unsafe")
                rr.count += 1
                if rr.count == len(rr.reads):
                    res[r_index] = None
                    yield self._finish(run, i, r_index, rr, save_charge, save_noise)
                done += 1
                if progress is not None:
                    progress(done)

    def integration_windows(self, pixel_time=0.0):
        """``(start, end)``, s from the start of the exposure: the span each
        integration's slope measures at a pixel of clock offset ``pixel_time`` (s,
        float or array of shape S; :meth:`noise.clock.Detector.pixel_time`), from its
        first resultant's mean read time to its last's (from its reset to its one
        resultant's mean time with one group).  Shape ``(nints,) + S``.

        The reset is the pixel's own in its integration's reset frame (rolling), or
        the start of the first read frame for every pixel (global,
        docs/CONVENTIONS.md); a pixel's reads come ``pixel_time`` into their frames.
        """
        ro, tf = self.readout, self.detector.frame_time
        pix = np.asarray(pixel_time, dtype=np.float64)
        tbar = ro.mean_times(tf, pix)                                # from the reset
        t0 = np.arange(ro.nints) * exposure_slots(1, ro.nreads) * tf    # reset frames
        t0 = t0.reshape((ro.nints,) + (1,) * pix.ndim)
        reset = t0 + (tf if ro.reset_mode == "global" else pix)
        first = tbar[0] if ro.ngroups > 1 else 0.0
        return reset + first, reset + tbar[-1]

    def light_curve_means(self):
        """Mean relative flux of every variable source over each integration's window
        (:meth:`integration_windows`), each stamp pixel at its own clock offset and
        the pixels weighted by their rate (what the source's summed CDS slopes
        measure; a source with no pixel on the array: at offset 0): (n_variable,
        nints) float64."""
        out = np.zeros((len(self.variable), self.readout.nints))
        for k, v in enumerate(self.variable):
            if v.index.size and v.weight.sum() > 0:
                out[k] = (self._pixel_means(v) * (v.weight / v.weight.sum())).sum(axis=1)
            else:
                out[k] = self._slope_means(v.light_curve, np.float64(0.0))
        return out

    def _pixel_means(self, v):
        """:meth:`_slope_means` of variable source ``v`` at each of its stamp pixels:
        (nints, npix)."""
        return self._slope_means(v.light_curve, self._pixel_time_flat(v.index))

    def _slope_means(self, lc, pix):
        """The relative flux a CDS slope of each integration measures at pixels of
        clock offset ``pix`` (array, shape S): the expected difference of its last
        and first resultants, each the mean of its reads' charge ``Q(t) = int from
        the reset to t`` of the light curve, over the difference of their mean read
        times (one group: its mean charge over its mean time, the value at the
        reset where that time is 0).  For one-read resultants it is the light
        curve's mean over :meth:`integration_windows`; for averaged groups each read
        counts (a probe: a step inside a 4-frame group, box mean 1.0 where the
        noise-free slopes read 0.96).  Shape (nints,) + S."""
        ro, tf = self.readout, self.detector.frame_time
        pix = np.asarray(pix, dtype=np.float64)
        t0 = np.arange(ro.nints) * exposure_slots(1, ro.nreads) * tf
        reset = t0.reshape((ro.nints, 1) + (1,) * pix.ndim) + \
            (tf if ro.reset_mode == "global" else pix)          # (nints, 1) + S
        times = ro.read_times(tf, pix)                           # from the reset
        tbar = ro.mean_times(tf, pix)

        def charge(t):                      # mean over a resultant's reads of Q(t)
            return lc.integral(reset, reset + t[None]).mean(axis=1)
        if ro.ngroups > 1:
            return (charge(times[-1]) - charge(times[0])) / (tbar[-1] - tbar[0])
        q = charge(times[0])
        width, at_reset, q = np.broadcast_arrays(tbar[0], lc(reset[:, 0]), q)
        return np.where(width > 0, q / np.where(width > 0, width, 1.0), at_reset)

    def source_windows(self, v):
        """:meth:`integration_windows` at the clock offset of the stamp pixel of
        ``v`` with the largest rate (offset 0 without any): the windows ``LCINTS``
        lists, ``(start, end)`` of shape (nints,)."""
        pix = self._pixel_time_flat(v.index[np.argmax(v.weight)]) if v.index.size \
            else 0.0
        return self.integration_windows(pix)

    def expected_rate(self, t1=None, t2=None):
        """Expected rate of collected charge (e-/s) per pixel, before IPC (after the
        QE flat, which is in the rates); light curves averaged over ``[t1, t2]``, by
        default over the integrations' windows at each pixel's own clock offset (the
        mean of their means, :meth:`integration_windows`: what the slopes measure;
        the exposure's span would count resets and gaps no read sees).  Shape (ny,
        nx), float64."""
        rate = self.rate.copy()
        if t1 is None and t2 is None:
            for v in self.variable:
                np.add.at(rate.ravel(), v.index,
                          v.weight * self._pixel_means(v).mean(axis=0))
            return rate
        det, ro = self.detector, self.readout
        t1 = 0.0 if t1 is None else t1
        t2 = exposure_slots(ro.nints, ro.nreads) * det.frame_time if t2 is None else t2
        for v in self.variable:
            mean = float(v.light_curve.integral(np.array([t1]), np.array([t2]))[0]) \
                / (t2 - t1)
            np.add.at(rate.ravel(), v.index, v.weight * mean)
        return rate

    def measured_rate(self, rate):
        """``rate`` after IPC (what a linear fit of the raw ramps recovers), e-/s."""
        out = np.asarray(rate, dtype=np.float64)
        if self.ipc_kernel is not None:
            out = apply_ipc(out, self.ipc_kernel, refmask=self.refmask)
        return out


def _even_runs(n, k):
    """``range(n)`` cut into ``k`` runs of nearly equal length (empty ones dropped)."""
    edges = np.linspace(0, n, k + 1).astype(int)
    return [range(a, b) for a, b in zip(edges[:-1].tolist(), edges[1:].tolist()) if b > a]


def _as_1d(name, value, dtype):
    """``value`` as a 1-D array of ``dtype`` (the same object when it already is)."""
    try:
        arr = np.asarray(value)
        if arr.dtype.kind not in "iuf" or arr.ndim != 1:
            raise TypeError
        return arr.astype(dtype, copy=False)
    except (TypeError, ValueError) as exc:
        raise ParameterTypeError(
            f"{name!r} must be a 1-D array of numbers, got {describe(value)}") from exc


def _poisson_or_gauss(g, lam, threshold):
    """Poisson below ``threshold``, rounded Gaussian N(lam, lam) above (approximation)."""
    out = np.empty(lam.shape, dtype=np.int64)
    big = lam > threshold
    out[~big] = poisson(g, lam[~big])
    if big.any():
        z = g.standard_normal(int(big.sum()), dtype=np.float32)
        out[big] = np.maximum(np.rint(lam[big] + np.sqrt(lam[big]) * z), 0)
    return out


