"""The random-number floor: the time to draw the variates a workload cannot avoid.

The **random-number floor** of a workload is the time to draw, in bulk, the variates
its exact model cannot avoid (DESIGN.md section 7).  Per materialised read: one
float32 normal per pixel (white noise); one normal per kept time-line sample of each
enabled 1/f series (correlated pink: ``frame_samples``; uncorrelated pink: ``n_out *
frame_samples``; ACN: ``2 * n_out * frame_samples / 2``; picture frame: ``ny +
nfoh``).  Per integration: one normal per pixel for kTC when enabled.  Per read
interval: one Poisson draw per pixel with charge, at the workload's typical (median)
mean ``lambda``.  The draws are split evenly across the threads, each thread with its
own ``Generator`` from ``SeedSequence.spawn``, filling its part of a preallocated,
pre-touched float32 buffer (reused in slabs of at most ``_SLAB`` variates so the
floor itself needs bounded memory); Poisson draws go through the same slabs.
"""

import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from noise.errors import ParameterError
from noise.fast.normal import standard_normal
from noise.fast.poisson import poisson

__all__ = ['floor_seconds', 'floor_counts', 'typical_lambda']


_SLAB = 1 << 24          # variates per floor slab (64 MB of float32)


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
    white = det.ny * det.nx if params.enabled("rd_noise") else 0
    return white + pink_samples_per_read(det, params)


def pink_samples_per_read(det, params):
    """1/f time-line samples of one materialised read (correlated and uncorrelated
    pink, ACN's two half-rate series, the picture frame's rows)."""
    nout = det.n_out_active
    L = det.frame_samples
    n = 0
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


def typical_lambda(rate, dt):
    """Median Poisson mean (e-) over the pixels with charge, for intervals ``dt`` (s)."""
    r = rate[rate > 0]
    return float(np.median(r) * dt) if r.size else 0.0
