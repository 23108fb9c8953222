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
convolving white Gaussian noise with a short FIR filter (4096 taps, designed by
frequency sampling and tapered), using FFT overlap-save in fixed blocks.  Coarser bands
are brought to the full rate by cubic (Keys, a = -1/2) interpolation, cascaded level by
level; each band's filter is pre-divided by the interpolator's response so the sum has
the target PSD.  Each band's crossover ``f_c = r_j / 16`` leaves the band far below its
own Nyquist, so interpolation images are negligible (< 1e-3 of the PSD).

Properties:

* **Non-periodic and continuous**: the series is a stationary process sampled on one
  unbroken time line (frames, overheads, resets, skipped frames and integrations
  included); there is no wrap-around.
* **Bounded memory**: a block of ~16k samples per band; nothing grows with the number of
  frames.
* **Chunk independent**: block ``b`` of band ``j`` of series ``s`` draws its white noise
  from its own stream ``SeedSequence(entropy, spawn_key=(..., s, j, b))``, so a sample
  depends only on its index, never on how samples are requested.  Blocks nobody asks
  for (skipped frames) are never computed; only the coarse bands, which cost 1/D of the
  fine band, run through them.
* **Cost**: ~1.03 normal draws per output sample plus two FFTs per block: about 1.5x the
  random-number floor of one draw per kept sample.

Normalisation (see :mod:`noise.params`): the level is set from the *realised* PSD of the
designed filters so that the expected variance over one frame of ``n`` samples, with
the frame mean removed, equals ``amp**2``::

    amp**2 = integral S(f) (1 - F_n(f)) df,   F_n(f) = [sin(pi f n/r) / (n sin(pi f/r))]^2
"""

import functools

import numpy as np
import scipy.fft as sfft

__all__ = ["PinkSeries", "pink_psd_shape", "realised_psd", "unit_frame_variance",
           "set_fft_workers"]

_D = 32          # decimation between bands
_K = 8           # band top at r_j / (2 K)
_ORDER = 4       # crossover steepness
_NTAPS = 4096    # FIR length per band
_NFFT = 16384    # overlap-save FFT length
_BLOCK = _NFFT - _NTAPS + 1
_MAX_RATIO = 512.0  # coarsest band: rate / f_min <= this, so its FIR resolves f_min
_GROUP = 8       # finest band: white noise drawn 8 blocks (~98k samples) per stream
_PAD = 64        # zero-padding factor when evaluating a filter's realised response


def pink_psd_shape(f, f_min, spectrum=None):
    """Unit-level one-sided PSD shape at frequencies ``f`` (Hz).

    ``1/f`` for ``f >= f_min`` and ``1/f_min`` below (stationary), or, if ``spectrum``
    (pairs of (f_Hz, psd)) is given, its log-log interpolation, constant beyond the
    table's ends and flat below ``f_min``.
    """
    f = np.maximum(np.asarray(f, dtype=float), f_min)
    if spectrum is None:
        return 1.0 / f
    tab = np.asarray(spectrum, dtype=float)
    return np.exp(np.interp(np.log(f), np.log(tab[:, 0]), np.log(tab[:, 1])))


def _lowpass(f, fc):
    return 1.0 / (1.0 + (f / fc) ** _ORDER)


def _keys_weights(D):
    """Keys cubic weights, shape (4, D), for fractional positions d / D."""
    t = np.arange(D) / D
    w = np.empty((4, D))
    w[0] = (-t**3 + 2 * t**2 - t) / 2
    w[1] = (3 * t**3 - 5 * t**2 + 2) / 2
    w[2] = (-3 * t**3 + 4 * t**2 + t) / 2
    w[3] = (t**3 - t**2) / 2
    return w


@functools.lru_cache(maxsize=1)
def _keys_table():
    """Fourier transform of the Keys cubic kernel on nu in [0, 0.5] cycles/sample."""
    t = np.linspace(-2.0, 2.0, 4097)
    a = np.abs(t)
    k = np.where(a <= 1, 1.5 * a**3 - 2.5 * a**2 + 1,
                 np.where(a < 2, -0.5 * a**3 + 2.5 * a**2 - 4 * a + 2, 0.0))
    nu = np.linspace(0.0, 0.5, 2049)
    resp = np.trapezoid(k[None, :] * np.cos(2 * np.pi * nu[:, None] * t[None, :]), t,
                        axis=1)
    return nu, resp


def _keys_response(nu):
    """Response of the cubic interpolator at ``nu`` cycles per coarse sample (<= 0.5)."""
    grid, resp = _keys_table()
    return np.interp(nu, grid, resp)


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

    Returns a tuple of ``(band_rate, H, f_grid, psd_grid)`` per band: the rfft of the
    FIR for overlap-save, and the realised one-sided PSD (per Hz, unit white input) on a
    dense linear grid up to the band's Nyquist, interpolation response included.
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
        target = pink_psd_shape(f, f_min, spectrum) * weight
        amp = np.sqrt(target * r / 2.0)     # (2/r)|H|^2 = S for unit white input
        if j > 0:
            amp /= _keys_response(f / r)
        h = sfft.irfft(amp, n=ngrid)
        h = np.roll(h, _NTAPS // 2)[:_NTAPS] * _taper(_NTAPS)
        H = sfft.rfft(h, n=_NFFT).astype(np.complex64)
        fg = np.arange(_PAD * _NTAPS // 2 + 1) * r / (_PAD * _NTAPS)
        psd = 2.0 / r * np.abs(sfft.rfft(h, n=_PAD * _NTAPS)) ** 2
        if j > 0:
            psd *= _keys_response(fg / r) ** 2
        bands.append((r, H, fg, psd))
    return tuple(bands)


def _fejer(f, n, rate):
    """Discrete Fejer kernel of an ``n``-sample mean at ``f`` (Hz), sample rate ``rate``."""
    x = np.pi * np.asarray(f, dtype=float) / rate
    with np.errstate(invalid="ignore", divide="ignore"):
        val = (np.sin(n * x) / (n * np.sin(x))) ** 2
    return np.where(x == 0, 1.0, val)


def realised_psd(f, rate, f_min, spectrum=None):
    """One-sided PSD (per Hz) at ``f`` of a unit-scale series as actually synthesised."""
    f = np.asarray(f, dtype=float)
    s = np.zeros(f.shape)
    for r, _, fg, psd in _design(float(rate), float(f_min), spectrum):
        inband = f <= r / 2
        s[inband] += np.interp(f[inband], fg, psd)
    return s


@functools.lru_cache(maxsize=64)
def unit_frame_variance(rate, n, f_min, spectrum=None):
    """Expected variance over ``n`` samples (mean removed) of a unit-scale series.

    ``integral S(f) (1 - F_n(f)) df`` of the realised PSD, on a log grid.
    """
    f = np.geomspace(f_min * 1e-3, rate / 2, 40000)
    integrand = realised_psd(f, rate, f_min, spectrum) * (1.0 - _fejer(f, n, rate))
    return float(np.trapezoid(integrand, f))


_FFT_WORKERS = [1]


def set_fft_workers(n):
    """Threads scipy.fft may use for batched band FFTs (results do not depend on it)."""
    _FFT_WORKERS[0] = max(1, int(n))


class _Band:
    """One band: white noise -> FIR by overlap-save, in fixed blocks of ``_BLOCK``.

    White noise is drawn in groups of ``group`` blocks (large draws run well in
    parallel threads): group ``g`` of series ``s`` draws from
    ``SeedSequence(entropy, spawn_key=keys[s] + (g + 1,))``.
    """

    _BATCH = 16   # blocks per batched FFT call

    def __init__(self, H, keys, entropy, group):
        self.H = H
        self.keys = [tuple(k) for k in keys]
        self.nseries = len(self.keys)
        self.entropy = entropy
        self.group = group
        self.pool = None
        self._white = {}
        self._out = {}

    def _draw(self, tasks):
        for s, g, out in tasks:
            ss = np.random.SeedSequence(self.entropy, spawn_key=self.keys[s] + (g + 1,))
            np.random.Generator(np.random.PCG64(ss)).standard_normal(out=out,
                                                                     dtype=np.float32)

    def _white_block(self, b):
        g, k = divmod(b, self.group)
        return self._white[g][:, k * _BLOCK:(k + 1) * _BLOCK]

    def _ensure(self, b0, b1):
        """Compute output blocks ``b0 .. b1`` (inclusive) that are not cached yet."""
        for b in [b for b in self._out if b < b0]:
            del self._out[b]
        missing = [b for b in range(b0, b1 + 1) if b not in self._out]
        if not missing:
            return
        first_group = (missing[0] - 1) // self.group
        for g in [g for g in self._white if g < first_group]:
            del self._white[g]
        groups = sorted({(b - 1) // self.group for b in missing}
                        | {b // self.group for b in missing})
        tasks = []
        for g in groups:
            if g not in self._white:
                w = np.empty((self.nseries, self.group * _BLOCK), dtype=np.float32)
                self._white[g] = w
                tasks.extend((s, g, w[s]) for s in range(self.nseries))
        if self.pool is not None and len(tasks) > 1:
            list(self.pool.map(self._draw, [[t] for t in tasks]))
        else:
            self._draw(tasks)
        for i in range(0, len(missing), self._BATCH):
            batch = missing[i:i + self._BATCH]
            x = np.empty((self.nseries, len(batch), _NFFT), dtype=np.float32)
            for n, b in enumerate(batch):
                x[:, n, :_NTAPS - 1] = self._white_block(b - 1)[:, _BLOCK - (_NTAPS - 1):]
                x[:, n, _NTAPS - 1:] = self._white_block(b)
            X = sfft.rfft(x, axis=-1, workers=_FFT_WORKERS[0])
            X *= self.H
            y = sfft.irfft(X, n=_NFFT, axis=-1, workers=_FFT_WORKERS[0])
            for n, b in enumerate(batch):
                self._out[b] = y[:, n, _NTAPS - 1:]

    def get(self, start, n):
        """Samples ``[start, start + n)``, shape (nseries, n), float32."""
        b0 = start // _BLOCK
        b1 = (start + n - 1) // _BLOCK
        self._ensure(b0, b1)
        if b0 == b1:
            off = start - b0 * _BLOCK
            return self._out[b0][:, off:off + n].copy()
        out = np.empty((self.nseries, n), dtype=np.float32)
        pos = start
        while pos < start + n:
            b, off = divmod(pos, _BLOCK)
            take = min(_BLOCK - off, start + n - pos)
            out[:, pos - start:pos - start + take] = self._out[b][:, off:off + take]
            pos += take
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
        Spawn-key prefix of each series; band ``j``, white-noise group ``g`` of series
        ``s`` draws from ``spawn_key = seed_keys[s] + (j, g + 1)``, so a series' values do not
        depend on which other series share the batch.

    Attributes
    ----------
    pool : concurrent.futures.Executor or None
        Threads used to draw white-noise blocks in parallel (results do not depend on
        it).
    """

    def __init__(self, rate, frame_samples, amplitudes, *, f_min, spectrum=None,
                 entropy, seed_keys):
        self.rate = float(rate)
        self.f_min = float(f_min)
        self.spectrum = spectrum
        self.amplitudes = np.asarray(amplitudes, dtype=float).ravel()
        self.nseries = self.amplitudes.size
        design = _design(self.rate, self.f_min, spectrum)
        if len(seed_keys) != self.nseries:
            raise ValueError("one seed key per amplitude is required")
        self.bands = [_Band(H, [tuple(k) + (j,) for k in seed_keys], entropy,
                            _GROUP if j == 0 else 1)
                      for j, (_, H, _, _) in enumerate(design)]
        self._weights = _keys_weights(_D).astype(np.float32)
        self.unit_sigma = np.sqrt(unit_frame_variance(self.rate, int(frame_samples),
                                                      self.f_min, spectrum))
        self.scale = (self.amplitudes / self.unit_sigma).astype(np.float32)

    @property
    def pool(self):
        return self.bands[0].pool

    @pool.setter
    def pool(self, pool):
        for band in self.bands:
            band.pool = pool

    def psd(self, f):
        """One-sided PSD (e-^2/Hz) of each series at ``f`` (Hz), shape (nseries,) + f.shape."""
        unit = realised_psd(f, self.rate, self.f_min, self.spectrum)
        return (self.scale.astype(float) ** 2)[(...,) + (None,) * np.ndim(unit)] * unit

    def _level_get(self, j, start, n):
        y = self.bands[j].get(start, n)
        if j + 1 < len(self.bands):
            y += self._interp_child(j + 1, start, n)
        return y

    def _interp_child(self, j, start, n):
        """Band ``j`` (and coarser) interpolated to band ``j-1``'s rate, [start, start+n)."""
        p0 = (start // _D) * _D
        q = -(-(start + n - p0) // _D)                  # coarse cells covered
        c = self._level_get(j, p0 // _D, q + 3)         # child samples i-1 .. i+2
        # explicit 4-tap sum: a BLAS matmul would leave OpenBLAS threads spinning on
        # the cores our own worker threads need
        w = self._weights
        y = c[:, 0:q, None] * w[0]
        y += c[:, 1:q + 1, None] * w[1]
        y += c[:, 2:q + 2, None] * w[2]
        y += c[:, 3:q + 3, None] * w[3]
        y = y.reshape(self.nseries, q * _D)
        return y[:, start - p0:start - p0 + n]

    def get(self, start, n):
        """Samples ``[start, start + n)`` of every series, shape (nseries, n), float32, e-.

        ``start`` is the absolute sample index on the exposure's time line.  Increasing
        access is cheapest (block caches) but any order gives the same values.
        """
        y = self._level_get(0, int(start), int(n))
        y *= self.scale[:, None]
        return y
