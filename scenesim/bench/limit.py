"""The limit of a simulation workload: what scenesim cannot avoid with its own tools.

Issue 16 defines the **limit** of a simulation workload as the sum of three costs, each
measured in the same run, with the same threads, best of ``repeats``:

* **draws**: the variates of the random-number floor (:mod:`scenesim.bench.floor`)
  drawn with scenesim's own samplers (:func:`noise.fast.normal.standard_normal`,
  :func:`noise.fast.poisson.poisson`), i.e. ``floor_seconds(..., sampler='scenesim')``;
* **inverse FFTs**: one inverse real FFT per kept 1/f sample
  (:func:`pink_samples`): complex64 spectra of ``nfft // 2 + 1`` bins transformed to
  ``nfft`` float32 samples with ``scipy.fft.irfft``, four transforms per call (as
  :mod:`noise.pink` batches them), split over the threads like the floor.  The
  default ``nfft = 32768`` is :mod:`noise.pink`'s finest block; every output sample
  is charged once (the synthesis itself also pays a forward FFT and an overlap of
  4096 per block, which the limit does not count);
* **write**: one write of the output file's bytes from memory to a new file in the
  output's directory (page cache; no ``fsync``, like the workload's own write).

The limit is a bound for the current method, not for physics: the distance
``wall / limit`` says how much is left to win without drawing fewer variates.

The **method floor** adds what the exact 1/f synthesis of :mod:`noise.pink` cannot
avoid on top of the limit: overlap-save filters a *time-domain* white window, so
every block of ``nfft - overlap`` new samples (28672 of 32768 at the finest level)
pays a forward FFT of its window besides the inverse one.  The method floor is the
draws, the forward and inverse FFTs of those blocks (:func:`fft_seconds` with
``forward=True, overlap=4096``) and the write.  ``wall / method floor`` is the
distance left for the implementation; ``method floor / limit`` is what the method
itself costs above the limit (the coarse levels and the interpolator's small FFTs
are still not counted: the method floor stays a lower bound).
"""

import os
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.fft as sfft

from noise.errors import ParameterError
from noise.pink import _NFFT_FINE, _OV
from scenesim.bench.floor import floor_seconds, pink_samples_per_read

__all__ = ["pink_samples", "transforms", "fft_seconds", "write_seconds", "limit_seconds"]

_BATCH = 4              # transforms per scipy call, as noise.pink batches them
_WRITE_CHUNK = 1 << 26  # bytes of the pre-touched write buffer (64 MB), reused


def pink_samples(det, params, n_reads):
    """Kept 1/f time-line samples of ``n_reads`` materialised reads.

    Per read, as the floor counts them (DESIGN.md section 7): ``frame_samples`` for
    correlated pink, per output with uncorrelated pink ``frame_samples``, per output
    with ACN two half-rate series of ``frame_samples // 2``, and ``ny + nfoh`` for the
    picture frame.

    Parameters
    ----------
    det : noise.Detector
    params : noise.NoiseParams or None
        ``None``: no noise, no 1/f samples.
    n_reads : int
        Materialised reads in total (all integrations).

    Returns
    -------
    int
    """
    if params is None:
        return 0
    return int(n_reads) * pink_samples_per_read(det, params)


def transforms(n_samples, nfft=_NFFT_FINE, overlap=0):
    """Transforms of length ``nfft`` that produce ``n_samples`` samples when each keeps
    ``nfft - overlap`` of its outputs: ``ceil(n_samples / (nfft - overlap))``.

    Parameters
    ----------
    n_samples : int
        Output samples (>= 0).
    nfft : int
        Transform length (even, >= 2).
    overlap : int
        Samples of each transform that are discarded (0 <= overlap < nfft).

    Returns
    -------
    int
    """
    n_samples, nfft, overlap = int(n_samples), int(nfft), int(overlap)
    if n_samples < 0:
        raise ParameterError(f"'n_samples' must be >= 0, got {n_samples}")
    if nfft < 2 or nfft % 2:
        raise ParameterError(f"'nfft' must be even and >= 2, got {nfft}")
    if not 0 <= overlap < nfft:
        raise ParameterError(f"'overlap' must be >= 0 and below 'nfft' = {nfft}, got "
                             f"{overlap}")
    return -(-n_samples // (nfft - overlap))


def fft_seconds(n_samples, threads, *, nfft=_NFFT_FINE, overlap=0, forward=False,
                repeats=3):
    """Seconds of the real FFTs that produce ``n_samples`` samples.

    Parameters
    ----------
    n_samples : int
        Output samples (>= 0); :func:`transforms` ``(n_samples, nfft, overlap)``
        transforms.
    threads : int
        Threads (>= 1); the transforms are split evenly, one ``scipy.fft`` call of
        four transforms at a time per thread (``workers=1``).
    nfft : int, keyword-only
        Transform length (even, >= 2).
    overlap : int, keyword-only
        Outputs of each transform discarded (0: the limit's one inverse FFT per
        sample; 4096: overlap-save at :mod:`noise.pink`'s finest level).
    forward : bool, keyword-only
        Also a forward ``rfft`` of a float32 window before each inverse transform
        (the method floor; the module notes).
    repeats : int, keyword-only
        Measure this many times and keep the fastest.

    Returns
    -------
    float
        Wall seconds.
    """
    ntrans, nfft, threads = transforms(n_samples, nfft, overlap), int(nfft), int(threads)
    if threads < 1:
        raise ParameterError(f"'threads' must be >= 1, got {threads}")
    if ntrans == 0:
        return 0.0
    calls = -(-ntrans // _BATCH)
    parts = [calls // threads + (1 if t < calls % threads else 0) for t in range(threads)]
    g = np.random.default_rng(0)
    if forward:                 # float32 windows, transformed forward each time
        data = [g.standard_normal((_BATCH, nfft), dtype=np.float32)
                for _ in range(threads)]
    else:                       # complex64 spectra, transformed back each time
        data = [(g.standard_normal((_BATCH, nfft // 2 + 1), dtype=np.float32)
                 + 1j * g.standard_normal((_BATCH, nfft // 2 + 1), dtype=np.float32)
                 ).astype(np.complex64) for _ in range(threads)]

    def work(t):
        for _ in range(parts[t]):
            x = sfft.rfft(data[t], axis=-1, workers=1) if forward else data[t]
            sfft.irfft(x, n=nfft, axis=-1, overwrite_x=forward, workers=1)

    best = np.inf
    pool = ThreadPoolExecutor(threads) if threads > 1 else None
    try:
        for _ in range(max(1, int(repeats))):
            t0 = time.perf_counter()
            if pool is None:
                work(0)
            else:
                list(pool.map(work, range(threads)))
            best = min(best, time.perf_counter() - t0)
    finally:
        if pool is not None:
            pool.shutdown()
    return best


def write_seconds(nbytes, directory=None, *, repeats=3):
    """Seconds to write ``nbytes`` from memory to a new file in ``directory``.

    Parameters
    ----------
    nbytes : int
        Bytes of the output (>= 0).
    directory : str or None
        Where the file is written (the workload's output file system); ``None``: the
        system's temporary directory.  The file is removed.
    repeats : int, keyword-only
        Measure this many times and keep the fastest.

    Returns
    -------
    float
        Wall seconds of ``open``, the writes of a pre-touched 64 MB buffer and
        ``close`` (page cache, no ``fsync``).
    """
    nbytes = int(nbytes)
    if nbytes < 0:
        raise ParameterError(f"'nbytes' must be >= 0, got {nbytes}")
    if nbytes == 0:
        return 0.0
    buf = np.ones(min(nbytes, _WRITE_CHUNK), dtype=np.uint8)
    view = memoryview(buf)
    best = np.inf
    for _ in range(max(1, int(repeats))):
        fd, path = tempfile.mkstemp(prefix=".bench-write-", dir=directory)
        os.close(fd)
        try:
            t0 = time.perf_counter()
            with open(path, "wb", buffering=0) as f:
                left = nbytes
                while left:
                    n = min(left, len(view))
                    f.write(view[:n])
                    left -= n
            best = min(best, time.perf_counter() - t0)
        finally:
            os.unlink(path)
    return best


def limit_seconds(n_normal, n_poisson, lam, n_pink, nbytes, threads, *, directory=None,
                  repeats=3):
    """The limit of a simulation workload and its three parts (module notes).

    Parameters
    ----------
    n_normal, n_poisson : int
        The floor's variates (:func:`scenesim.bench.floor.floor_counts`).
    lam : float
        Mean of the Poisson draws, e-.
    n_pink : int
        Kept 1/f samples (:func:`pink_samples`).
    nbytes : int
        Bytes of the output file (0: the workload writes none).
    threads : int
    directory : str or None, keyword-only
        File system of the write.
    repeats : int, keyword-only

    Returns
    -------
    dict
        ``draws``, ``fft``, ``write`` and their sum ``limit``; ``fft_method`` (the
        forward and inverse FFTs of the overlap-save blocks) and the method floor
        ``method = draws + fft_method + write``; seconds.
    """
    draws = floor_seconds(n_normal, n_poisson, lam, threads, repeats=repeats,
                          sampler="scenesim") if (n_normal or n_poisson) else 0.0
    fft = fft_seconds(n_pink, threads, repeats=repeats)
    fft_method = fft_seconds(n_pink, threads, overlap=_OV, forward=True, repeats=repeats)
    write = write_seconds(nbytes, directory, repeats=repeats)
    return dict(draws=draws, fft=fft, write=write, limit=draws + fft + write,
                fft_method=fft_method, method=draws + fft_method + write)
