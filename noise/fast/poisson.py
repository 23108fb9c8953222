"""Exact Poisson variates for small means by vectorised inversion.

Why
---
The charge engine draws one Poisson variate per pixel per read interval, with means
``lam = rate * dt`` that are mostly small (0.01-10 e-).  For ``lam < 10`` numpy's
``Generator.poisson`` uses the multiplication method: per element, multiply uniforms
until the product falls below ``exp(-lam)``, i.e. ``lam + 1`` uniforms and a scalar
loop per draw (~20-40 ns per draw here).  This module draws the same distribution
with a single uniform per element and a few cheap whole-array passes.

Method
------
Inversion by sequential search (Devroye 1986, *Non-Uniform Random Variate Generation*,
ch. X.3, "inversion by sequential search"): with ``U ~ Uniform[0, 1)``,

    X = min{k >= 0 : U <= F(k)},     F(k) = sum_{j<=k} p_j,
    p_0 = exp(-lam),   p_k = p_{k-1} * lam / k,

so that ``P(X = k) = F(k) - F(k-1) = p_k``.  Vectorised: all elements start at
``k = 0`` with ``R = U - p_0``; each pass updates ``p *= lam; p /= k; R -= p`` on the
*active* elements (``R > 0``, i.e. ``U > F(k-1)``) and counts the passes each element
survives.  ``F(k)`` is non-decreasing in floating point too (adding ``p >= 0``), so an
element that stops never restarts and ``X = #{k : R_k > 0}``.  When the active set has
shrunk below half of the arrays being processed, it is compressed (``nonzero`` and
``take``), so late passes touch only the few elements still in the tail.  The uniform
is drawn into the output buffer (viewed as float64) and ``R`` is updated there in
place, which saves one array allocation per call.  Pass 0 is the fast path of tiny
means: ``X = 0`` wherever ``U <= exp(-lam)`` (97.5 % of the elements at
``lam = 0.025``), and only the rest is searched further.

Routing: means above ``small`` go to ``g.poisson`` (PTRS for ``lam >= 10``).  So do
the means above ``_FEW_LAM = 1`` when there are at most ``_FEW = 256`` of them (a
star on a faint background): the search runs about ``max(lam)`` passes of ~6 numpy
calls (~3-4 us each pass for a small active set), so a handful of bright elements
would cost ~10-20 passes, while ``g.poisson`` draws them in ~50 ns each.  Both
samplers are exact, so the routing changes run time, not the law.  The elements that
go to ``g.poisson`` keep their place in the inversion with their mean set to 0 (their
uniform is drawn and unused) when they are at most half of the array, which is
cheaper than gathering and scattering the rest; otherwise only the others are
gathered for the inversion.

Exactness
---------
The only departures from the exact Poisson law are float64 rounding: ``U`` is a
multiple of 2**-53 and each ``R_k`` carries an absolute rounding error of at most
about ``(k + 2) * 2**-53``, so each ``P(X <= k)`` is off by < ``(k + 3) * 1.2e-16``.
Guard: the search stops after ``k_max`` passes, the smallest ``k`` with
``P(X > k | lam_max) < 1e-15`` for the largest mean in the call (bounded with
``P(X > k) <= p_{k+1} / (1 - lam / (k + 2))``; ``k_max = 44`` at ``lam = 10``).  Elements
still active then (probability < 1e-15 each, or because ``F`` saturated just below
``U`` by rounding, or ``p`` underflowed) are redrawn with ``g.poisson`` from the full
law; this changes the distribution by < 1e-15 in total variation.  ``lam = 0`` gives
``p_0 = 1`` and ``R = U - 1 < 0``, i.e. exactly 0, from the same single uniform.
Means above ``small`` are drawn with ``g.poisson`` (PTRS, Hormann 1993), exact.

Random-number consumption is fixed by the input: ``g.random`` for the inversion (one
float64 per element of the inversion array, in array order: every element, or only
the elements not routed to ``g.poisson`` when those are more than half), then
``g.poisson`` for the rare guard leftovers, then ``g.poisson`` for the routed
elements in array order.  The same generator state and means therefore give the same
output.  It is *not* the same stream as ``g.poisson(lam)``.

One mean shared by most elements
--------------------------------
A frame's read interval is the same for every pixel after the first read, so a uniform
background gives most pixels the *same* mean.  When a call of at least 4096 means has
one value held by at least half of them (16 evenly spaced probes propose it, one
comparison pass confirms it), every element is drawn from that mean by **guide-table
inversion** (Chen & Asau 1974; Devroye 1986, ch. III.2.4) and the other elements are
then overwritten by their own draws: with ``g.poisson`` in one call when fewer than
``OTHERS_NUMPY_BELOW = 8192`` of them (the sources' pixels, whose many small passes of
the search would hold the GIL while other threads draw), else by the rules here,
recursively.  The table splits
``[0, 1)`` into ``M = 2**16`` buckets; ``guide[b]`` is the value ``X(u)`` common to
every ``u`` of bucket ``b``, or a mark when ``F`` steps inside it.  A draw takes 16
random bits ``b`` (four per raw 64-bit output of the bit generator) and one table
look-up; only in a marked bucket (probability about ``k_max / M``, < 0.3 %) does it draw
a 53-bit ``v`` and invert ``u = (b + v) / M`` by binary search on ``F``.  ``u`` is
thereby uniform to 69 bits where it matters and the law is exact up to the float64
values of ``F`` (scipy's ``pdtr``, relative error ~1e-15), as for the inversion.  A
dominant mean of 0 gives zeros without any draw.  Cost: ~4-5 ns per element instead of
9-40 ns (for means up to 100; larger ones keep the rules above).  Random-number
consumption is still fixed by the input values alone.

Cost model
----------
Per element: one uniform (~2.4 ns), one ``exp`` (~1 ns, SIMD), then about ``lam + 1``
passes of ~6 vectorised operations (~0.2 ns each per element) over a shrinking set,
plus compressions; numpy's multiplication method runs a scalar loop with one uniform
and a branch per step.  Python overhead is ~10 numpy calls per pass, negligible for
arrays of >~10^4 elements.  On this machine (x86-64, AVX-512, numpy 2.4, one thread)
fresh memory is expensive (~350 us per MB of first-touched pages, i.e. ~2.7 ns per
float64 element per new array), so allocations are kept few.

Inversion is faster than numpy's PTRS up to means of ~20; the default ``small = 10``
keeps numpy's branch for every mean where numpy itself switches to it.  Arrays of
fewer than ``NUMPY_BELOW = 2048`` means go to ``g.poisson`` whole (there the per-call
overhead of the passes dominates).  ``python -m noise.fast.poisson`` prints ns per
draw of both samplers on this machine (the measured table is in BENCHMARKS.md).
"""

import functools
import math
import numbers
import time

import numpy as np
from scipy.special import pdtr

from noise.errors import ParameterError

__all__ = ["poisson", "guide_table", "k_max", "k_max_exact", "GUIDE_BITS", "NUMPY_BELOW",
           "OTHERS_NUMPY_BELOW"]

#: Largest mean ``Generator.poisson`` accepts (numpy's ``POISSON_LAM_MAX``).
_LAM_MAX = float(np.iinfo(np.int64).max - np.sqrt(np.iinfo(np.int64).max) * 10)
#: Largest allowed ``small``: beyond it inversion is slower than PTRS by far, and the
#: guard ``k_max`` stays well below the uint8 pass counter's range.
_SMALL_MAX = 100.0
#: Tail mass left to the ``g.poisson`` fallback.
_TAIL = 1e-15
#: Compress the active set when fewer than this fraction of the processed elements
#: are still active (measured optimum between 0.3 and 0.5).
_COMPRESS = 0.5
#: When at most ``_FEW`` elements have a mean above ``_FEW_LAM``, they are drawn with
#: ``g.poisson`` (see :func:`poisson`).
_FEW = 256
_FEW_LAM = 1.0
#: Arrays with fewer elements go to ``g.poisson`` whole: there numpy's per-element loop
#: beats the per-pass overhead of the search (measured: 256 means 9 vs 17-44 us, 1024
#: means 26-58 vs 29-132 us, 2048 means 30-107 vs 43-148 us; equal near 4096).
NUMPY_BELOW = 2048
#: The elements left after a dominant mean's guide-table draws (:func:`poisson`: the
#: pixels of sources over a uniform background, a wide spread of means, many above
#: ``small``) go to ``g.poisson`` whole when fewer than this.  There the search's
#: ~35 passes of small numpy calls hold the GIL most of the time: with 2 threads
#: drawing different chunks they ran 1.9-2.2x slower than alone, while numpy's one
#: call for the whole remainder runs alone as fast up to ~8192 elements and keeps its
#: speed with 2 threads (star-field remainders of 2048-32768 elements, 32 arrays,
#: best of 3: 8192 elements 12.3 ms serial either way; on 2 threads 23.6 ms for the
#: search against 8.0 ms for numpy).
OTHERS_NUMPY_BELOW = 8192


def k_max(lam_max):
    """A cap ``k`` with ``P(X > k) < 1e-15`` for ``X ~ Poisson(lam_max)``.

    Evaluated (and cached) at ``lam_max`` rounded up to a multiple of 1/64: the tail
    grows with the mean, so the cap of the rounded mean is valid for ``lam_max``.
    """
    if lam_max <= 0.0:
        return 0
    return k_max_exact(math.ceil(lam_max * 64.0) / 64.0)


@functools.lru_cache(maxsize=4096)
def k_max_exact(lam_max):
    """Smallest ``k`` with ``P(X > k) < 1e-15`` for ``X ~ Poisson(lam_max)``.

    Uses ``P(X > k) <= p_{k+1} / (1 - lam / (k + 2))`` for ``k + 2 > lam`` (the
    ratios ``p_{j+1} / p_j = lam / (j + 1)`` of the tail terms are at most
    ``lam / (k + 2)``), with ``p_k`` evaluated in logs so nothing underflows.
    """
    if lam_max <= 0.0:
        return 0
    k = int(math.floor(lam_max))
    while True:
        log_p = -lam_max + (k + 1) * math.log(lam_max) - math.lgamma(k + 2)
        ratio = lam_max / (k + 2)
        if ratio < 1.0 and log_p - math.log1p(-ratio) < math.log(_TAIL):
            return k
        k += 1


def _inversion(g, lam, out):
    """Fill ``out`` with Poisson(``lam``) variates by sequential-search inversion.

    Parameters
    ----------
    g : numpy.random.Generator
    lam : ndarray, shape (n,), float64, C-contiguous
        Means, all in ``[0, _SMALL_MAX]``.
    out : ndarray, shape (n,), int64, C-contiguous
        Output; also used as the float64 work buffer of the residuals ``R``.
    """
    n = lam.size
    if n == 0:
        return out
    limit = k_max(float(lam.max()))
    resid = out.view(np.float64)
    g.random(out=resid)                      # U, one per element, in array order
    p = np.empty(n)
    np.negative(lam, out=p)
    np.exp(p, out=p)                         # p_0 = exp(-lam)
    np.subtract(resid, p, out=resid)         # R_0 = U - F(0)
    active = np.greater(resid, 0.0)
    n_act = int(np.count_nonzero(active))
    counts = active.view(np.uint8).copy()    # passes survived since last compression
    idx = None                               # None: the arrays still cover all of out
    lam_a = lam
    base = 0                                 # X >= base for elements of the arrays
    k = 0
    since = 1
    while True:
        if n_act < _COMPRESS * active.size or n_act == 0 or k == limit or since == 255:
            sel = active.nonzero()[0]
            if idx is None:
                # R is no longer needed where it lives: keep the active R's, then
                # overwrite the shared buffer with the counts.
                resid = resid[sel]
                np.copyto(out, counts, casting="unsafe")
                idx = sel
            else:
                resid = resid[sel]
                total = counts.astype(np.int64)
                total += base
                out[idx] = total
                idx = idx[sel]
            if n_act == 0:
                return out
            lam_a = lam_a[sel]
            if k == limit:
                # Guard: tail mass < 1e-15 (or rounding saturation); redraw exactly.
                out[idx] = g.poisson(lam_a)
                return out
            p = p[sel]
            base = k + 1
            since = 0
            counts = np.zeros(n_act, np.uint8)
            active = np.empty(n_act, bool)
        k += 1
        since += 1
        np.multiply(p, lam_a, out=p)
        np.divide(p, k, out=p)               # p_k = p_{k-1} * lam / k
        np.subtract(resid, p, out=resid)     # R_k = U - F(k)
        np.greater(resid, 0.0, out=active)
        np.add(counts, active.view(np.uint8), out=counts)
        n_act = int(np.count_nonzero(active))


# ------------------------------------------------------------ one mean, many elements
#: Arrays at least this long are checked for a dominant mean (:func:`_dominant`).
_SHARED_MIN = 4096
#: Largest common mean drawn from a guide table (larger ones straddle more buckets).
_SHARED_MAX = 100.0
#: Guide-table resolution: buckets of width 2**-16 of the uniform.
GUIDE_BITS = 16


@functools.lru_cache(maxsize=64)
def guide_table(lam):
    """Guide table and CDF of Poisson(``lam``), ``0 < lam <= _SHARED_MAX``.

    ``guide[b]`` is the value ``X(u) = min{k : u < F(k)}`` shared by every ``u`` of
    bucket ``[b, b + 1) / M`` (``M = 2**16``), or 255 when ``F`` steps inside the bucket
    (uint8: ``k_max(100) < 255``; a 64 kB table that stays in cache).
    ``F(k)`` is scipy's regularised incomplete gamma ``pdtr`` (relative error ~1e-15)
    up to ``k_max`` (the same ``P(X > k_max) < 1e-15`` cap as the inversion).
    """
    m = 1 << GUIDE_BITS
    cdf = pdtr(np.arange(k_max(lam) + 1, dtype=np.float64), lam)
    edges = np.arange(m + 1, dtype=np.float64) / m
    lo = np.searchsorted(cdf, edges[:-1], side="right")
    hi = np.searchsorted(cdf, np.nextafter(edges[1:], 0.0), side="right")
    guide = np.where(lo == hi, lo, 255).astype(np.uint8)
    guide.flags.writeable = False
    cdf.flags.writeable = False
    return guide, cdf


def _shared(g, lam, n, out):
    """``out[:] =`` ``n`` Poisson(``lam``) draws of one mean, by guide-table inversion.

    Inversion of ``u = (b + v) / M`` with the bucket ``b`` 16 random bits and, only
    where the bucket straddles a step of ``F`` (probability ~``k_max / M``), ``v`` a
    53-bit float64 uniform: ``u`` is then uniform to 69 bits there, and elsewhere the
    bucket alone fixes ``X``.  Exact to the float64 rounding of ``F`` (as the
    inversion); ``u`` beyond ``F(k_max)`` (probability < 1e-15) is redrawn with
    ``g.poisson``.  Cost ~3 ns per draw against 9-40 ns for the searches.
    """
    if lam == 0.0:
        out[:] = 0
        return
    guide, cdf = guide_table(lam)
    # 16-bit buckets: the four 16-bit slices of each raw 64-bit output of the bit
    # generator (PCG64's output bits are all uniform and independent)
    b = g.bit_generator.random_raw(-(-n // 4)).view(np.uint16)[:n]
    k = np.take(guide, b)       # = guide[b]; 2.7x faster than fancy indexing here
    s = (k == 255).nonzero()[0]
    out[:] = k
    if s.size:
        u = (b[s] + g.random(s.size)) * (1.0 / (1 << GUIDE_BITS))
        ks = np.searchsorted(cdf, u, side="right")
        beyond = ks >= cdf.size
        if beyond.any():
            ks[beyond] = g.poisson(lam, int(beyond.sum()))
        out[s] = ks


def _dominant(flat):
    """A mean held by at least half of ``flat`` (float64, 1-D), or None.

    16 evenly spaced probes propose the most frequent value; one pass confirms it.
    """
    step = (flat.size - 1) / 15.0
    probes = [float(flat[int(k * step)]) for k in range(16)]
    c = max(set(probes), key=probes.count)      # 16 values: plain Python is fastest
    if probes.count(c) < 6:
        return None
    if not c <= _SHARED_MAX:
        return None
    return c


def poisson(g, lam, *, small=10.0):
    """Exact Poisson variates; inversion for means ``<= small``, numpy above.

    Parameters
    ----------
    g : numpy.random.Generator
        Source of randomness (used, not copied: its state advances).
    lam : array_like of float, any shape, e- (or any count unit)
        Means, finite and ``>= 0`` (at most numpy's limit ~9.2e18).  Converted to
        float64.
    small : float, keyword-only, default 10.0
        Elements with ``lam <= small`` are drawn by vectorised inversion (one uniform
        each); larger ones with ``g.poisson``, and so are the elements above 1 when
        there are at most 256 of them, and arrays of fewer than 2048 means (see the
        module docstring).
        ``0 <= small <= 100``.

    Returns
    -------
    ndarray, same shape as ``lam``, int64
        Independent Poisson draws, element ``i`` with mean ``lam[i]``; exactly 0 where
        ``lam == 0``.

    Raises
    ------
    noise.errors.ParameterError
        If ``g`` is not a Generator, ``lam`` holds a negative, NaN, infinite or too
        large value, or ``small`` is outside ``[0, 100]``.  Raised before any draw.

    Notes
    -----
    Deterministic for a given generator state, but a different stream from
    ``g.poisson(lam)``; see the module docstring for the method and its exactness.
    """
    if not isinstance(g, np.random.Generator):
        raise ParameterError(f"'g' must be a numpy.random.Generator, got {type(g).__name__}")
    if isinstance(small, bool) or not isinstance(small, numbers.Real) \
            or not 0.0 <= float(small) <= _SMALL_MAX:
        raise ParameterError(f"'small' must be a real number in [0, {_SMALL_MAX:g}], "
                             f"got {small!r}")
    small = float(small)
    try:
        lam = np.asarray(lam, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"'lam' must be an array of real numbers, got {lam!r}") from exc
    flat = np.ascontiguousarray(lam).reshape(-1)
    if flat.size:
        lo, hi = flat.min(), flat.max()
        if not (lo >= 0.0 and hi <= _LAM_MAX):
            bad = flat[~((flat >= 0.0) & (flat <= _LAM_MAX))][0]
            raise ParameterError(f"'lam' must be finite and in [0, {_LAM_MAX:.4g}], "
                                 f"got {bad!r}")
    if flat.size >= _SHARED_MIN:
        c = _dominant(flat)
        if c is not None:
            other = (flat != c).nonzero()[0]
            if 2 * other.size <= flat.size:
                # Most elements share one mean (a uniform background over a frame
                # whose pixels all integrate the same interval): a guide table for
                # all of them, then the others overwritten with their own draws.
                out = np.empty(flat.size, np.int64)
                _shared(g, c, flat.size, out)
                if other.size >= OTHERS_NUMPY_BELOW:
                    out[other] = poisson(g, flat[other], small=small)
                elif other.size:
                    out[other] = g.poisson(flat[other])
                return out.reshape(lam.shape)
    if flat.size and (lo > small or flat.size < NUMPY_BELOW):
        return g.poisson(flat).astype(np.int64, copy=False).reshape(lam.shape)
    out = np.empty(flat.size, np.int64)
    is_large = None
    if flat.size and hi > small:
        is_large = flat > small
    if flat.size and hi > _FEW_LAM and small > _FEW_LAM:
        # A few means above _FEW_LAM would keep the search running for ~lam passes
        # over an almost empty active set: draw them with g.poisson instead.
        over = flat > _FEW_LAM
        if np.count_nonzero(over) <= _FEW:
            is_large = over
    if is_large is None:
        _inversion(g, flat, out)
        return out.reshape(lam.shape)
    large_idx = is_large.nonzero()[0]
    if 2 * large_idx.size <= flat.size:
        # Inversion over the whole array with the large means set to 0 (their
        # uniforms are drawn and unused: cheaper than gathering and scattering).
        _inversion(g, np.where(is_large, 0.0, flat), out)
    else:
        small_idx = (~is_large).nonzero()[0]
        out_small = np.empty(small_idx.size, np.int64)
        _inversion(g, flat[small_idx], out_small)
        out[small_idx] = out_small
    out[large_idx] = g.poisson(flat[large_idx])
    return out.reshape(lam.shape)


def _benchmark(lams=(0.03, 0.3, 1.0, 3.0, 10.0), n=131072, repeats=5):
    """Best-of-``repeats`` ns per draw of ``g.poisson`` and :func:`poisson`.

    Returns a list of ``(lam, ns_numpy, ns_here)`` for constant-mean arrays of ``n``
    float64 elements, one thread.
    """
    g = np.random.default_rng(12345)
    rows = []
    for value in lams:
        lam = np.full(n, value)
        best = [math.inf, math.inf]
        for _ in range(repeats):
            for j, func in enumerate((lambda: g.poisson(lam), lambda: poisson(g, lam))):
                t0 = time.perf_counter()
                func()
                best[j] = min(best[j], time.perf_counter() - t0)
        rows.append((value, best[0] / n * 1e9, best[1] / n * 1e9))
    return rows


if __name__ == "__main__":
    print(f"{'lam':>8} {'numpy ns':>9} {'here ns':>8} {'speed-up':>8}")
    for value, t_np, t_here in _benchmark():
        print(f"{value:8.3g} {t_np:9.1f} {t_here:8.1f} {t_np / t_here:8.2f}")
