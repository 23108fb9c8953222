"""Streaming, non-periodic 1/f (pink) noise of a fixed PSD, in bounded memory.

Why not the original method
---------------------------
NG (Rauscher 2015, Sec. 4.1) filters 2x as many white samples as needed in Fourier
space, keeps the first half, and rescales the result to a sample sigma.  That needs the
whole cube's time line in memory at once (one FFT of twice its length), and the
rescaling makes the PSD level depend on the cube length.

Method used here: multirate overlap-save synthesis
--------------------------------------------------
The target one-sided PSD ``S(f)`` (``1/f`` above ``f_min``, flat below, or a user
shape) is split into bands, ``S = sum_j S * P_j`` with smooth complementary weights
(``P_j`` telescoping products of ``1/(1 + (f/f_c)^4)``, so ``sum_j P_j = 1`` exactly).
Band ``j`` is synthesised at its own sample rate ``r_j = r_0 / D**j`` (``D = 32``) by
convolving white noise with a FIR filter ``h_j`` (4096 taps, designed by frequency
sampling and tapered), using FFT overlap-save with an overlap of 4096: output block
``b`` of level ``j`` (``B = N - 4096`` samples; ``N = 32768`` at the finest level,
8192 at the coarser ones, which need few samples) is the valid part of the circular
convolution of the white window ``w[b B : b B + N]``.  Each band's crossover
``f_c = r_j / 16`` leaves it far below its own Nyquist.

Coarser bands are brought to the finer rate *inside the finer level's FFT*: level
``j + 1`` is zero-stuffed by ``D`` and filtered by a Kaiser-windowed sinc interpolator
``g`` (4097 taps at the fine rate, 140 dB: pass-band ripple and stop-band leakage
< 2e-7 in amplitude, pass band up to 0.43 of the coarse rate).  The DFT of a
zero-stuffed window is the coarse window's DFT repeated, and ``g`` removes every
repeat, so the finer block's spectrum is ``X_w H_j + G C`` where ``C`` is the
``N/D``-point rfft of the coarse samples ``[b B/D, b B/D + N/D)``, added on its
``N/(2D) + 1`` bins only.  One inverse FFT gives the band and every coarser band at
once: the interpolation costs a 1024-point FFT per 28672 output samples instead of
passes over the output, and leaves no spectral images (the dropped bins carry < 2e-7 of
``g``'s gain).  Since ``B`` and the overlap are multiples of ``D``, every output sample
is the same linear combination of white and coarse samples whatever the block: the
process is exactly stationary, and its samples equal the direct linear convolutions
``sum_m h[m] w[p + 4096 - m] + sum_m g[m] u[p + 4096 - m]`` (``u`` the zero-stuffed
coarse series) to float32 rounding.

Blocks are computed four at a time (scipy's FFT runs four transforms at once with
SIMD: batches of a multiple of four rows cost half as much per transform), and the
white noise is laid out as the FFT input, one row per block: group ``g`` (four blocks)
draws its ``4 B`` new samples per series from one stream in one call (few large calls
keep the second thread from waiting on the GIL), copies them into the rows and copies
each row's first 4096 samples from the end of the previous row.

Properties:

* **Non-periodic and continuous**: the series is a stationary process sampled on one
  unbroken time line (frames, overheads, resets, skipped frames and integrations
  included); there is no wrap-around.
* **Bounded memory**: a few blocks per level; nothing grows with the number of frames.
* **Chunk independent**: white-noise group ``g`` of level ``j`` of series ``s`` is
  drawn from its own stream ``SeedSequence(entropy, spawn_key=seed_keys[s] + (j, g +
  1))`` (the 4096 samples before group 0 from key ``(j, 0)``), so a sample depends only
  on its index, never on how samples are requested, on the thread that computed it, or
  on the other series of the batch.  Blocks nobody asks for (skipped frames) are never
  computed; only the coarse levels, which cost 1/D of the finest, run through them.
* **Cost** (one core, measured): one float32 normal per output sample (3-6 ns with the
  Box-Muller sampler of :mod:`noise.fast.normal`, exact to float32 in the body and to 53-bit
  resolution in the tails; numpy's ziggurat costs 9-11 ns) plus ~5 ns of FFT work and
  ~1 ns of copies; :meth:`PinkSeries.plan` hands a range of samples of all the
  object's series to a thread pool as one independent task (their draws and FFTs
  batched: :class:`noise.generator.NoiseGenerator` puts the series of up to 8 outputs
  in one object).  Requests are served by whole groups, so up to one
  group (115k samples) per series is drawn ahead of the request and used by the next one.

Normalisation (see :mod:`noise.params`): the level is set from the *realised* PSD of the
designed filters so that the expected variance over one frame of ``n`` samples, with
the frame mean removed, equals ``amp**2``::

    amp**2 = integral S(f) (1 - F_n(f)) df,   F_n(f) = [sin(pi f n/r) / (n sin(pi f/r))]^2
"""

import functools
import math
import time

import numpy as np
import scipy.fft as sfft

from noise.errors import ParameterError
from noise.params import check_pink_spectrum
from noise.validate import check_array, check_float, check_int
from noise.fast.normal import standard_normal
from noise.fast.seedhash import pcg64
from noise.streams import KeyedStreams, root_seed

__all__ = ["PinkSeries", "pink_psd_shape", "realised_psd",
           "unit_frame_variance", "set_fft_workers", "measure_psd_error"]

_D = 32          # decimation between bands
_K = 8           # band top at r_j / (2 K)
_ORDER = 4       # crossover steepness
_NTAPS = 4096    # FIR length per band
_OV = 4096       # overlap-save overlap: >= _NTAPS - 1 and a multiple of _D
_NFFT_FINE = 32768    # finest level (blocks of 28672: ~4 % cheaper per sample than 16384)
_NFFT_COARSE = 8192   # coarser levels (blocks of 4096: they need few samples)
_INTERP_DB = 140.0        # Kaiser interpolator attenuation
_MAX_RATIO = 512.0  # coarsest band: rate / f_min <= this, so its FIR resolves f_min
_GROUP = 4       # blocks per white-noise stream at the two finest levels (115k and
                 # 16k samples); one block per stream at the coarser levels
_QUAD = 4        # blocks per FFT batch at the two finest levels (one at coarser levels,
                 # which rarely need a new block)
_SEEDS_AHEAD = 8  # white-noise groups whose stream seeds are hashed in one call
_PAD = 64        # zero-padding factor when evaluating a filter's realised response


def _check_psd_args(rate, f_min, spectrum, *, with_rate=True):
    """The checked ``(rate, f_min, spectrum)`` of the public PSD functions: ``rate``
    > 0 (unless not ``with_rate``), ``0 < f_min < rate / 2``, ``spectrum`` None or
    pairs."""
    f_min = check_float("f_min", f_min, minimum=0.0, strict_min=True)
    if with_rate:
        rate = check_float("rate", rate, minimum=0.0, strict_min=True)
        if f_min >= rate / 2:
            raise ParameterError(
                f"'f_min' = {f_min!r} Hz must be below the Nyquist frequency "
                f"rate / 2 = {rate / 2:g} Hz")
    if spectrum is not None:
        spectrum = check_pink_spectrum("spectrum", spectrum)
    return rate, f_min, spectrum


def pink_psd_shape(f, f_min, spectrum=None):
    """Unit-level one-sided PSD shape at frequencies ``f`` (Hz).

    ``1/f`` for ``f >= f_min`` and ``1/f_min`` below (stationary), or, if ``spectrum``
    (pairs of (f_Hz, psd)) is given, its log-log interpolation, constant beyond the
    table's ends and flat below ``f_min``.

    Raises
    ------
    noise.errors.ParameterError
        ``f`` not finite real numbers, ``f_min`` not > 0, or a bad ``spectrum``.
    """
    f = check_array("f", f)
    _, f_min, spectrum = _check_psd_args(None, f_min, spectrum, with_rate=False)
    return _psd_shape(f, f_min, spectrum)


def _psd_shape(f, f_min, spectrum=None):
    """:func:`pink_psd_shape` without the argument checks."""
    f = np.maximum(np.asarray(f, dtype=float), f_min)
    if spectrum is None:
        return 1.0 / f
    tab = np.asarray(spectrum, dtype=float)
    return np.exp(np.interp(np.log(f), np.log(tab[:, 0]), np.log(tab[:, 1])))


def _lowpass(f, fc):
    return 1.0 / (1.0 + (f / fc) ** _ORDER)


def _nfft(level):
    """Overlap-save FFT length of ``level`` (0: finest)."""
    return _NFFT_FINE if level == 0 else _NFFT_COARSE


@functools.lru_cache(maxsize=1)
def _interp_filter():
    """Kaiser-windowed sinc interpolator by ``_D`` at the fine rate.

    Returns
    -------
    g : ndarray, shape (_OV + 1,)
        Taps (gain ``_D``, centred on tap ``_OV / 2``).
    nu : ndarray
        Frequency grid, cycles per fine sample, up to ``1 / _D``.
    resp : ndarray
        ``|G(nu)| / _D`` on that grid (~1 in the pass band, < 2e-7 beyond 0.5 / _D).
    """
    n = _OV + 1
    m = np.arange(n) - _OV / 2
    beta = 0.1102 * (_INTERP_DB - 8.7)
    width = (_INTERP_DB - 7.95) / (14.36 * (n - 1))
    fc = 0.5 / _D - width / 2
    g = _D * 2 * fc * np.sinc(2 * fc * m) * np.kaiser(n, beta)
    nfine = 1 << 20
    resp = np.abs(sfft.rfft(g, n=nfine)[:nfine // _D + 1]) / _D
    nu = np.arange(resp.size) / nfine
    return g, nu, resp


@functools.lru_cache(maxsize=4)
def _interp_dft(nfft):
    """``nfft``-point DFT of the interpolator on the bins carrying the coarse level."""
    return sfft.rfft(_interp_filter()[0], n=nfft)[:nfft // _D // 2 + 1].astype(np.complex64)


def _interp_response(nu):
    """``|G| / D`` of the interpolator at ``nu`` cycles per fine sample (0 beyond 1/D)."""
    _, grid, resp = _interp_filter()
    return np.interp(nu, grid, resp, right=0.0)


def _taper(n):
    """Tukey window with 20 % cosine tapers at each end."""
    w = np.ones(n)
    m = n // 5
    ramp = 0.5 * (1 - np.cos(np.pi * (np.arange(m) + 0.5) / m))
    w[:m] = ramp
    w[-m:] = ramp[::-1]
    return w


@functools.lru_cache(maxsize=32)
def _design(rate, f_min, spectrum):
    """Design the band filters for a series at ``rate`` Hz.

    Returns a tuple of ``(band_rate, H, f_grid, psd_grid, h)`` per band: the rfft
    of the FIR at the level's overlap-save length (complex128), the realised one-sided
    PSD (per Hz, unit white input) on a dense linear grid up to the band's Nyquist,
    with the response of every interpolation stage included, and the taps.
    """
    nband = 1
    while rate / _D ** (nband - 1) / f_min > _MAX_RATIO:
        nband += 1
    bands = []
    for j in range(nband):
        r = rate / _D ** j
        ngrid = 4 * _NTAPS
        f = np.arange(ngrid // 2 + 1) * r / ngrid
        weight = np.ones_like(f)
        for i in range(1, j + 1):           # low-passes of all finer crossovers
            weight *= _lowpass(f, rate / _D ** i / (2 * _K))
        if j < nband - 1:                   # high-pass at this band's lower crossover
            weight *= 1.0 - _lowpass(f, r / _D / (2 * _K))
        target = _psd_shape(f, f_min, spectrum) * weight
        amp = np.sqrt(target * r / 2.0)     # (2/r)|H|^2 = S for unit white input
        h = sfft.irfft(amp, n=ngrid)
        h = np.roll(h, _NTAPS // 2)[:_NTAPS] * _taper(_NTAPS)
        H = sfft.rfft(h, n=_nfft(j))
        fg = np.arange(_PAD * _NTAPS // 2 + 1) * r / (_PAD * _NTAPS)
        psd = 2.0 / r * np.abs(sfft.rfft(h, n=_PAD * _NTAPS)) ** 2
        for i in range(1, j + 1):           # interpolation from r_i up to r_(i-1)
            psd *= _interp_response(fg / (rate / _D ** (i - 1))) ** 2
        bands.append((r, H, fg, psd, h))
    return tuple(bands)


def _fejer(f, n, rate):
    """Discrete Fejer kernel of an ``n``-sample mean at ``f`` (Hz), sample rate ``rate``."""
    x = np.pi * np.asarray(f, dtype=float) / rate
    with np.errstate(invalid="ignore", divide="ignore"):
        val = (np.sin(n * x) / (n * np.sin(x))) ** 2
    return np.where(x == 0, 1.0, val)


def realised_psd(f, rate, f_min, spectrum=None):
    """One-sided PSD (per Hz) at ``f`` of a unit-scale series as actually synthesised.

    ``rate`` (Hz, > 0) is the series' sample rate; ``0 < f_min < rate / 2``.
    """
    f = check_array("f", f)
    rate, f_min, spectrum = _check_psd_args(rate, f_min, spectrum)
    return _realised_psd(f, rate, f_min, spectrum)


def _realised_psd(f, rate, f_min, spectrum=None):
    """:func:`realised_psd` without the argument checks."""
    f = np.asarray(f, dtype=float)
    s = np.zeros(f.shape)
    for r, _, fg, psd, _ in _design(float(rate), float(f_min), spectrum):
        inband = f <= r / 2
        s[inband] += np.interp(f[inband], fg, psd)
    return s


def unit_frame_variance(rate, n, f_min, spectrum=None):
    """Expected variance over ``n`` samples (mean removed) of a unit-scale series.

    ``integral S(f) (1 - F_n(f)) df`` of the realised PSD, on a log grid; ``rate``
    (Hz, > 0) is the sample rate, ``n >= 1``, ``0 < f_min < rate / 2``.
    """
    rate, f_min, spectrum = _check_psd_args(rate, f_min, spectrum)
    return _unit_frame_variance(rate, check_int("n", n, minimum=1), f_min, spectrum)


@functools.lru_cache(maxsize=64)
def _unit_frame_variance(rate, n, f_min, spectrum=None):
    """:func:`unit_frame_variance` without the argument checks (cached)."""
    f = np.geomspace(f_min * 1e-3, rate / 2, 40000)
    integrand = _realised_psd(f, rate, f_min, spectrum) * (1.0 - _fejer(f, n, rate))
    return float(np.trapezoid(integrand, f))


@functools.lru_cache(maxsize=64)
def _unit_total_variance(rate, f_min, spectrum=None):
    """Variance of a unit-scale series itself (its realised PSD's integral), what a
    sample wanders around the process's mean: more than :func:`unit_frame_variance`,
    which leaves out the frequencies below one frame (cached; arguments as there)."""
    f = np.geomspace(f_min * 1e-3, rate / 2, 40000)
    s = _realised_psd(f, rate, f_min, spectrum)
    return float(np.trapezoid(s, f) + s[0] * f[0])     # + the flat PSD below f[0]


_FFT_WORKERS = [1]


def set_fft_workers(n):
    """Threads scipy.fft may use inside :meth:`PinkSeries.get` (results do not change).

    The threaded path (:meth:`PinkSeries.plan`) always uses one per task.
    """
    _FFT_WORKERS[0] = max(1, int(n))


def _runs(blocks, group, quad):
    """Quads (``quad`` aligned blocks) covering ``blocks``, as runs of consecutive
    quads within one white-noise group, each run a list of block indices.

    Blocks are computed by whole quads: scipy's FFT processes four transforms at once
    with SIMD, so batches of a multiple of four rows run twice as fast.
    """
    quads = sorted({b // quad for b in blocks})
    runs = []
    for q in quads:
        same_group = q * quad // group == runs[-1][0] * quad // group if runs else False
        if same_group and q == runs[-1][-1] + 1:
            runs[-1].append(q)
        else:
            runs.append([q])
    return [list(range(r[0] * quad, (r[-1] + 1) * quad)) for r in runs]


class _Level:
    """One level of the multirate cascade: white noise -> FIR, plus the coarser level.

    Output block ``b`` is samples ``[b B, (b+1) B)`` of this level's time line (unit
    scale), ``B = nfft - _OV``; it is the valid part of the circular convolution of the
    white window ``w[b B, b B + nfft)``.  The white noise is stored directly in that
    layout, one row per block: white-noise group ``g`` (``G`` blocks, one stream) draws
    the ``B`` new samples ``w[b B + _OV, (b+1) B + _OV)`` of each of its rows in order,
    and each row's first ``_OV`` samples are copied from the previous row (for the
    group's first row, from the previous group; for group 0 from a stream of ``_OV``
    samples keyed ``0``).  The FFT then reads the rows in place.
    """

    def __init__(self, H, keys, entropy, group, quad, child, nfft):
        self.H = H                      # (nfft // 2 + 1,) complex64, unit scale
        self.keys = [tuple(k) for k in keys]
        self.nseries = len(self.keys)
        self.group = group              # blocks per white-noise stream
        self.quad = quad                # blocks per FFT unit (divides group)
        self.child = child              # coarser _Level or None
        self.nfft = nfft
        self.B = nfft - _OV
        self.nc = nfft // _D            # coarse samples per window
        self.bc = self.B // _D          # coarse samples per block
        self._G = _interp_dft(nfft) if child is not None else None
        self._white = {}                # group -> (nseries, group, nfft) float32
        self._head = set()              # groups whose first row's head is filled
        self._free = []                 # evicted group arrays, for reuse
        self._cache = {}                # block -> (nseries, B) float32, unit scale
        self._child_arr = None
        self._child0 = 0
        self._streams = KeyedStreams(entropy, self.keys)   # keys[s] + (g + 1,)
        self._seeds = {}                # group -> (nseries, 4) stream seeds, ahead

    # ---------------------------------------------------------------- white noise
    def _groups_for(self, runs):
        """White-noise groups that ``runs`` read (a run's first row needs the previous
        group's last row unless its head is already filled)."""
        groups = set()
        for run in runs:
            g = run[0] // self.group
            groups.add(g)
            if run[0] % self.group == 0 and g not in self._head:
                groups.add(g - 1)
        return sorted(groups)

    def _alloc(self, groups):
        """Allocate the missing groups (serial); return those that need drawing."""
        new = [g for g in groups if g not in self._white]
        for g in new:
            if g < 0:
                self._white[g] = np.empty((self.nseries, 1, self.nfft), dtype=np.float32)
            else:
                self._white[g] = self._free.pop() if self._free else np.empty(
                    (self.nseries, self.group, self.nfft), dtype=np.float32)
        return new

    @staticmethod
    def _draw(bitgen, out):
        standard_normal(np.random.Generator(bitgen), out)

    def _fill(self, g):
        """Draw white-noise group ``g`` of every series (releases the GIL)."""
        arr = self._white[g]
        seeds = self._seeds.pop(g, None)
        if seeds is None:               # the seeds of this and the next groups at once
            grid = self._streams.states_grid(np.arange(g + 1, g + 1 + _SEEDS_AHEAD))
            self._seeds = {g + i: grid[:, i] for i in range(1, _SEEDS_AHEAD)}
            seeds = grid[:, 0]
        for s, state in enumerate(seeds):
            bitgen = pcg64(state)
            if g < 0:                    # the head of group 0: w[0, _OV)
                self._draw(bitgen, arr[s, 0, self.B:])
                continue
            # one call for the whole group (few large calls: the sampler's small
            # per-block numpy calls would otherwise contend for the GIL)
            tmp = np.empty((self.group, self.B), dtype=np.float32)
            self._draw(bitgen, tmp)
            arr[s, :, _OV:] = tmp
            for k in range(1, self.group):
                arr[s, k, :_OV] = arr[s, k - 1, self.B:]

    def _evict(self, b0, first_todo):
        for b in [b for b in self._cache if b < b0]:
            del self._cache[b]
        if first_todo is not None:
            g0 = first_todo // self.group - 1        # keep the previous group (its tail)
            for g in [g for g in self._white if g < g0]:
                arr = self._white.pop(g)
                self._head.discard(g)
                if g >= 0 and len(self._free) < 4:   # recycle: reused memory stays hot
                    self._free.append(arr)

    def _prep_child(self, b_first, b_last):
        """Coarse samples needed by blocks ``b_first .. b_last`` (serial in the child)."""
        if self.child is not None:
            self._child0 = b_first * self.bc
            self._child_arr = self.child.get(self._child0,
                                             (b_last - b_first) * self.bc + self.nc)

    # ------------------------------------------------------------------- compute
    def _compute(self, run):
        """Blocks ``run`` (consecutive, one group): array (nseries, len(run), B)."""
        g, k0, nb = run[0] // self.group, run[0] % self.group, len(run)
        arr = self._white[g]
        if k0 == 0 and g not in self._head:
            arr[:, 0, :_OV] = self._white[g - 1][:, -1, self.B:]
            self._head.add(g)
        X = sfft.rfft(arr[:, k0:k0 + nb], axis=-1, workers=_FFT_WORKERS[0])
        X *= self.H
        if self.child is not None:
            off = run[0] * self.bc - self._child0
            c = np.empty((self.nseries, nb, self.nc), dtype=np.float32)
            for i in range(nb):
                c[:, i] = self._child_arr[:, off + i * self.bc:off + i * self.bc + self.nc]
            C = sfft.rfft(c, axis=-1, overwrite_x=True, workers=_FFT_WORKERS[0])
            C *= self._G
            X[..., :C.shape[-1]] += C
        y = sfft.irfft(X, n=self.nfft, axis=-1, overwrite_x=True, workers=_FFT_WORKERS[0])
        return y[..., _OV:]

    def get(self, start, n):
        """Samples ``[start, start + n)``, shape (nseries, n), float32, unit scale."""
        B = self.B
        b0, b1 = start // B, (start + n - 1) // B
        todo = [b for b in range(b0, b1 + 1) if b not in self._cache]
        self._evict(b0, todo[0] if todo else None)
        if todo:
            runs = _runs(todo, self.group, self.quad)
            for g in self._alloc(self._groups_for(runs)):
                self._fill(g)
            self._prep_child(runs[0][0], runs[-1][-1])
            for run in runs:
                y = self._compute(run)
                for i, b in enumerate(run):
                    self._cache[b] = y[:, i]
        out = np.empty((self.nseries, n), dtype=np.float32)
        for b in range(b0, b1 + 1):
            lo, hi = max(start, b * B), min(start + n, (b + 1) * B)
            out[:, lo - start:hi - start] = self._cache[b][:, lo - b * B:hi - b * B]
        for b in [b for b in self._cache if b < b1]:
            del self._cache[b]
        return out


class PinkSeries:
    """A batch of independent streaming 1/f series sharing one PSD and sample rate.

    Parameters
    ----------
    rate : float
        Sample rate of the series, Hz (e.g. ``1/dt`` for a pixel-rate time line).
    frame_samples : int
        Samples per frame of this series; each amplitude is the expected sigma over
        one frame with the frame mean removed (see :mod:`noise.params`).
    amplitudes : array_like, shape (nseries,)
        Amplitude of each series, e-.
    f_min : float
        PSD flat below this frequency, Hz.
    spectrum : tuple of (f, psd) pairs or None
        User PSD shape instead of 1/f.
    entropy : int or sequence of int
        Root entropy of the exposure's ``SeedSequence``.
    seed_keys : sequence of tuple of int
        Spawn-key prefix of each series; level ``j``, white-noise group ``g`` of series
        ``s`` draws from ``spawn_key = seed_keys[s] + (j, g + 1)``, so a series' values
        do not depend on which other series share the batch.
    """

    def __init__(self, rate, frame_samples, amplitudes, *, f_min, spectrum=None,
                 entropy, seed_keys):
        self.rate = float(rate)
        self.f_min = float(f_min)
        self.spectrum = spectrum
        self.amplitudes = np.asarray(amplitudes, dtype=float).ravel()
        self.nseries = self.amplitudes.size
        if len(seed_keys) != self.nseries:
            raise ParameterError(
                f"'seed_keys' needs one key per amplitude: {len(seed_keys)} keys for "
                f"{self.nseries} amplitudes")
        design = _design(self.rate, self.f_min, spectrum)
        level = None
        for j in reversed(range(len(design))):
            H = design[j][1]
            group, quad = (_GROUP, _QUAD) if j <= 1 else (1, 1)
            level = _Level(H.astype(np.complex64), [tuple(k) + (j,) for k in seed_keys],
                           entropy, group, quad, level, _nfft(j))
        self._top = level
        self.unit_sigma = np.sqrt(_unit_frame_variance(self.rate, int(frame_samples),
                                                      self.f_min, spectrum))
        self.scale = (self.amplitudes / self.unit_sigma).astype(np.float32)

    def psd(self, f):
        """One-sided PSD (e-^2/Hz) of each series at ``f`` (Hz), shape (nseries,) + f.shape.
        """
        unit = _realised_psd(f, self.rate, self.f_min, self.spectrum)
        return (self.scale.astype(float) ** 2)[(...,) + (None,) * np.ndim(unit)] * unit

    def get(self, start, n):
        """Samples ``[start, start + n)`` of every series, shape (nseries, n), float32, e-.

        ``start`` is the absolute sample index on the exposure's time line.  Increasing
        access is cheapest (block caches) but any order gives the same values.
        """
        y = self._top.get(int(start), int(n))
        y *= self.scale[:, None]
        return y

    def plan(self, start, n, out):
        """Prepare samples ``[start, start + n)`` into ``out`` as a task for a thread pool.

        Parameters
        ----------
        start, n : int
            Sample range, as in :meth:`get`.
        out : ndarray, shape (nseries, n) or lead + (n,), float32
            Destination (e-); may be a strided view.  Its leading axes, read in C
            order, are the series (``prod(lead) == nseries``): e.g. pairs of series
            interleaved sample by sample into ``k`` lines are the ``(k, 2, n)`` view
            ``lines.reshape(k, n, 2).transpose(0, 2, 1)``.  Filled when the task has
            run.

        Returns
        -------
        callable
            The task: writes the blocks already computed, draws the white noise,
            computes the coarse levels, runs the overlap-save FFTs and writes the rest
            of ``out``.  Tasks of different ``PinkSeries`` are independent and may run
            on any threads; the values equal :meth:`get`'s.  Do not call :meth:`get`
            or :meth:`plan` on this object until the task has run.
        """
        start, n = int(start), int(n)
        if (not isinstance(out, np.ndarray) or out.ndim < 2 or out.shape[-1] != n
                or math.prod(out.shape[:-1]) != self.nseries):
            raise ParameterError(
                f"'out' must be an ndarray whose leading axes hold the {self.nseries} "
                f"series and whose last axis the {n} samples, got shape "
                f"{getattr(out, 'shape', type(out).__name__)}")
        lev = self._top
        b0, b1 = start // lev.B, (start + n - 1) // lev.B
        todo = [b for b in range(b0, b1 + 1) if b not in lev._cache]
        lev._evict(b0, todo[0] if todo else None)
        cached = [(b, lev._cache[b]) for b in range(b0, b1 + 1) if b in lev._cache]
        runs = _runs(todo, lev.group, lev.quad) if todo else []
        groups = lev._alloc(lev._groups_for(runs))
        return functools.partial(self._work, cached, runs, groups, start, n, out)

    def _work(self, cached, runs, groups, start, n, out):
        for b, y in cached:
            self._write(y, b, start, n, out)
        if runs:
            lev = self._top
            lev._prep_child(runs[0][0], runs[-1][-1])
            for g in groups:
                lev._fill(g)
            for run in runs:
                self._run(run, start, n, out)

    def _write(self, y, b, start, n, out):
        B = self._top.B
        lead = out.shape[:-1]
        lo, hi = max(start, b * B), min(start + n, (b + 1) * B)
        np.multiply(y[:, lo - b * B:hi - b * B].reshape(lead + (hi - lo,)),
                    self.scale.reshape(lead + (1,)), out=out[..., lo - start:hi - start])

    def _run(self, run, start, n, out):
        lev = self._top
        B = lev.B
        y = lev._compute(run)
        lo = max(run[0], start // B)                 # blocks of the run in the request
        hi = min(run[-1], (start + n - 1) // B)
        full0 = lo if lo * B >= start else lo + 1    # ... and those entirely inside
        full1 = hi if (hi + 1) * B <= start + n else hi - 1
        for b in {lo, hi}:
            if lo <= hi and not full0 <= b <= full1:
                self._write(y[:, b - run[0]], b, start, n, out)
        if full0 <= full1:
            k, i0 = full1 - full0 + 1, full0 - run[0]
            lead = out.shape[:-1]
            dst = out[..., full0 * B - start:(full1 + 1) * B - start].view()
            dst.shape = lead + (k, B)        # splits the last axis: always a view
            np.multiply(y[:, i0:i0 + k].reshape(lead + (k, B)),
                        self.scale.reshape(lead + (1, 1)), out=dst)
        for i, b in enumerate(run):
            if (b + 1) * B > start + n:              # needed by a later request
                lev._cache[b] = y[:, i]


# ---------------------------------------------------------------- error measurement
def measure_psd_error(*, rate=1e5, frame_samples=1073676, f_min=1e-4,
                      decades=((30.0, 300.0), (300.0, 3e3), (3e3, 3e4)), nperseg=2 ** 17,
                      nseg=64, rng=None):
    """Error of the 1/f synthesis against exact 1/f theory, per decade, and its cost.

    Theory: ``S(f) = c / f`` with ``c`` fixed by the amplitude definition
    (:mod:`noise.params`) for the ideal 1/f spectrum, integrated here independently of
    the synthesis filters.

    Parameters
    ----------
    rate : float
        Sample rate, Hz (default: the 10 us pixel clock).
    frame_samples : int
        Samples per frame, for the amplitude definition (default: full-frame H2RG).
    f_min : float
        PSD flat below this, Hz.
    decades : sequence of (f_lo, f_hi)
        Frequency ranges, Hz.
    nperseg, nseg : int
        Averaged periodogram: ``nseg`` Hann segments of ``nperseg`` samples.
    rng : int, SeedSequence, Generator or None, keyword-only
        Seed of the simulated series (None: fresh OS entropy).

    Returns
    -------
    dict
        ``design``: per decade, max ``|log10(P_realised / P_theory)|`` of the PSD the
        filters realise (no sampling noise);
        ``measured``: per decade, max over ten log-spaced sub-bands of
        ``|log10(mean P_hat / P_theory)|`` of a simulated unit-amplitude series;
        ``measured_sigma``: per decade, the largest standard error (dex) of those
        sub-band means, ``log10(e) sqrt(k / (nseg * nbins))`` with ``k = 1.94`` for the
        correlation of neighbouring Hann-window bins;
        ``measured_kurtosis`` and ``kurtosis_sigma``: sample excess kurtosis of the
        series' first differences (where the finest band dominates) and its standard
        error ``sqrt(24 / n)``;
        ``seconds_per_msample``: synthesis time per million samples (one thread).
        Decades are keyed ``'30-300 Hz'`` etc.
    """
    rate, f_min = float(rate), float(f_min)
    fi = np.geomspace(f_min * 1e-5, rate / 2, 400001)
    c_theory = 1.0 / np.trapezoid((1.0 - _fejer(fi, frame_samples, rate))
                                  / np.maximum(fi, f_min), fi)
    entropy, key = root_seed(rng)
    series = PinkSeries(rate, frame_samples, [1.0], f_min=f_min, entropy=entropy,
                        seed_keys=[key + (0,)])
    t0 = time.perf_counter()
    y = series.get(0, nseg * nperseg)[0]
    seconds = time.perf_counter() - t0
    seg = y.astype(np.float64).reshape(nseg, nperseg)
    seg -= seg.mean(axis=1, keepdims=True)
    w = np.hanning(nperseg)
    spec = np.fft.rfft(seg * w, axis=1)
    phat = (2.0 / (rate * np.sum(w ** 2)) * np.abs(spec) ** 2).mean(axis=0)
    fbin = np.fft.rfftfreq(nperseg, 1.0 / rate)
    # neighbouring periodogram bins of a tapered segment are correlated (Hann: 4/9 at
    # lag 1, 1/36 at lag 2): a mean over many bins has variance (1 + 2 sum rho_k) / N
    c = np.abs(np.fft.fft(w ** 2)[1:8]) / np.sum(w ** 2)
    var_factor = 1.0 + 2.0 * np.sum(c ** 2)
    design, measured, sigma = {}, {}, {}
    for lo, hi in decades:
        key = f"{lo:g}-{hi:g} Hz"
        f = np.geomspace(lo, hi, 400)
        p_real = float(series.scale[0]) ** 2 * _realised_psd(f, rate, f_min)
        design[key] = float(np.max(np.abs(np.log10(p_real * f / c_theory))))
        edges = np.geomspace(lo, hi, 11)
        worst, worst_sigma = 0.0, 0.0
        for a, b in zip(edges[:-1], edges[1:]):
            sel = (fbin >= a) & (fbin < b)
            ratio = np.mean(phat[sel] * fbin[sel] / c_theory)
            worst = max(worst, abs(np.log10(ratio)))
            worst_sigma = max(worst_sigma,
                              np.log10(np.e) * np.sqrt(var_factor / (nseg * sel.sum())))
        measured[key] = float(worst)
        sigma[key] = float(worst_sigma)
    d = np.diff(y.astype(np.float64))
    d -= d.mean()
    kurt = float(np.mean(d ** 4) / np.mean(d ** 2) ** 2 - 3.0)
    return {"design": design, "measured": measured, "measured_sigma": sigma,
            "measured_kurtosis": kurt, "kurtosis_sigma": float(np.sqrt(24.0 / d.size)),
            "seconds_per_msample": seconds / (y.size / 1e6)}
