"""The rates at which a fitter reports the Poisson part of a slope's variance, and
weights its GLS solve.

Why not the pixel's own rate
----------------------------
The slope is a weighted mean of the rate estimates ``d_i``, and its variance
``V = V_read + q_p f`` (``q_p = w^T C_poisson w``) is linear in the unknown true
rate ``f``.  stcal and Brandt's fitramp evaluate it at the pixel's own fitted rate,
``V_hat = V_read + q_p max(f_hat, 0)``.  That makes ``V_hat`` correlated with the
error ``e = f_hat - f``: for Gaussian ``e`` of variance ``V``, by Stein's lemma
``E[e^2 / V_hat] ~ 1 + 3 kappa^2`` without the clip, ``kappa = q_p sqrt(V) / V`` being
the relative change of ``V_hat`` per standard deviation of the rate; the clip at 0
removes the low side, so at the lowest fluxes the mean falls below 1.  ``kappa^2``
is ``~1/counts`` where Poisson noise dominates (harmless) but reaches
``q_p^2 / V_read`` where read noise dominates: 20 JWST frames of 10.737 s with 10 e-
read noise give ``E[(f_hat - f)^2 / V_hat] = 0.93`` at 0.01 e-/s and 1.04 at
0.1 e-/s; the uneven 9-resultant table 0.91 and 1.08 (closed-form integrals;
``expected_z2`` in the tests computes these).

The neighbourhood estimate (:func:`local_rate`)
-----------------------------------------------
A rate that is *not* correlated with the pixel's own error removes the effect to
first order: the error of ``V_hat`` then only enters through Jensen's inequality,
``E[V / V_hat] - 1 ~ q_p^2 Var(r) / V^2``.  The default ``variance_rate='local'`` of
:func:`scenesim.rampfit.fit_ramps` is an empirical-Bayes estimate of that kind.  The
prior mean of the pixel's rate is the median ``m`` of its 24 neighbours in a 5 x 5
box (centre excluded, so independent of the pixel's own noise; one clip at 4 robust
sigma leaves out isolated hot or hit neighbours, each of which would otherwise move
the median by ~0.1 sigma); its mean squared error is ``tau^2 + (pi/2) V_m / n``,
with ``tau^2`` the spread of the neighbours' rates beyond their noise, estimated from
their interquartile range (``s = IQR / 1.349``) as
``max(s^2 - V_m (1 + 2 x 2.33 / sqrt(n)), 0)``: the noise variance ``V_m`` at rate
``m`` plus two standard errors of ``s^2`` (``2.33 sigma^2 / sqrt(n)``
asymptotically), so that flat regions do not read noise in ``s`` as structure.  The
posterior mean would be ``w max(f_hat, 0) + (1 - w) max(m, 0)``,
``w = MSE / (MSE + V_m)``: in flat regions ``w = w_flat = c / (1 + c)``,
``c = (pi / 2) / n`` (0.06 for 24 neighbours); at sources, gradients and flat-field
structure ``w -> 1`` (the pixel's own rate, where ``kappa`` is small because such
pixels are bright).  The variance rate keeps only the own share *beyond* that of a
flat neighbourhood, ``w' = (w - w_flat) / (1 - w_flat)``,
``r = w' max(f_hat, 0) + (1 - w') max(m, 0)``: in a flat region it is the
neighbours' median alone, so that ``V_hat`` is independent of the pixel's own
error (at rate 0 with read noise 1 e- and 100 reads the 6 % own share made
``E[z^2]`` 0.05 lower than ``E[V / V_hat]``).  A pixel 3 to 5 sigma away from
``m`` (hot pixel, unresolved source) moves linearly to ``w = 1``, as do pixels with
fewer than 8 usable neighbours; pixels with ``kappa^2 < 3e-3`` (own-rate error of
``E[z^2]``, ``3 kappa^2``, below 1 %) keep their own rate without the neighbourhood
sort.  Its measured calibration is in ``docs/VALIDATION_FIT.md``.

The limit at rate 0
-------------------
The Poisson part ``q_p r`` cannot be told from 0 by 24 neighbours when
``q_p sqrt(Var(m))`` is not small against ``V`` (``kappa > ~0.3``: rates ~0 with read
noise <~ 5 e- and long ramps): ``r >= 0`` then has a mean of ~0.4 standard errors of
the median above a true rate of 0, and the reported errors are conservative,
``E[z^2] = E[V_read / V_hat] < 1`` (0.72 at read noise 1 e- and 100 reads, 0.54 at
1000 reads, 0.39 at 0.1 e-; tested against that prediction in
``tests/rampfit/test_edges.py``).  They are never too small there.  A dark or
low-background exposure whose rate is known (a dark calibration) should pass it as
``variance_rate``: the weights and the variance are then those at that rate, and
``E[z^2] = 1``.  In the photon-counting regime (less than ~1 expected photon per
ramp and read noise well below 1 e-) the slope errors are discrete, a median of
neighbours' counts is biased low, and the mean of ``z^2`` is dominated by the rare
pixels with a photon: no Gaussian error describes them.

Faint isolated sources
----------------------
A source that stands less than ~3 sigma above its neighbours (a few e- per ramp on a
dark field) is not told from a noise excursion: its variance rate is mostly the
neighbours' median, so its reported error leaves out most of its own shot noise.
Measured (``docs/VALIDATION_FIT.md``): single pixels at 0.02 e-/s (6 e- per ramp),
read noise 2 e-, 30 reads of 10 s: ``E[z^2]`` 2.35-2.67 (own rate, ``'fit'``:
1.44-1.64); at 30 e- per ramp 1.09-1.13.  No rate taken from the data is calibrated
there; pass the sources' rates as ``variance_rate`` (an array).

The weight rate (:func:`local_rates`)
-------------------------------------
GLS weights evaluated at the pixel's own rate are correlated with its noise
(:mod:`scenesim.rampfit.fitter`).  The fitter solves the pixels that use their
neighbours again with the covariance at a *weight rate*:
``w' max(f_hat, 0) + (1 - w') g(m)`` with ``g`` the non-negative garrote of the
neighbours' median, ``g(m) = m - k^2 MSE / m`` for ``m > k sqrt(MSE)`` and 0 below
(``k = 2``): near 0, where the neighbours cannot tell the rate from 0, the weights
lean toward the read-noise weights, whose loss at a small true rate is bounded
(at most the OLS loss, ~7 % in sigma for 20 groups), while weights at a small
positive rate that is in truth 0 lose without bound once ``kappa >> 1``
(std/sqrt(V_opt) 1.3-1.8 at read noise 0.1 e-); far above 0 ``g(m) -> m``.  The
first round of the fitter leaves the own rate out entirely (``own_share=False``):
the first fit's slopes of dark pixels have heavy tails that would make them look
like sources.

Cost: one sort of 24 neighbours per pixel that needs it, in chunks of
:data:`scenesim.rampfit.solver.CHUNK_ELEMS` values, on the caller's thread pool.
"""

import math

import numpy as np

from scenesim.rampfit.solver import CHUNK_ELEMS, TINY

__all__ = ["local_rate", "local_rates", "uses_neighbours"]

_F32 = np.float32
_LOCAL_HALF = 2          # 5 x 5 neighbourhood of the variance rate
_LOCAL_MIN = 8           # fewer usable neighbours: the pixel's own rate
_LOCAL_CLIP = 4.0        # neighbours beyond 4 robust sigma of their median are left out
_LOCAL_KAPPA2 = 3e-3     # own rate where (d var / d rate)^2 Var(rate) / var^2 is below
_IQR_SIGMA = 1.349       # interquartile range of a unit normal
_IQR_VAR = 2.33          # sd of (IQR / 1.349)^2 is 2.33 sigma^2 / sqrt(n) (asymptotic)
_WEIGHT_LOWER = 2.0      # weight rate: the neighbours' median shrunk by 2 of its errors


def local_rate(slope, var_read, pcoef, *, usable, pool=None):
    """Rate for the reported Poisson variance: own rate shrunk toward the neighbours.

    Empirical-Bayes estimate (module notes): the prior of a pixel's rate is the
    median ``m`` of the fitted rates of its 24 neighbours in a 5 x 5 box (centre
    excluded, unusable pixels skipped, neighbours more than 4 robust standard
    deviations from the first median left out), with a mean squared error
    ``tau^2 + (pi / 2) V_m / n``, where ``tau^2 = max(s^2 - V_m, 0)`` is the spread
    of the neighbours' rates beyond their noise (``s`` = interquartile range / 1.349),
    ``V_m`` the pixel's slope variance at rate ``m`` and ``n`` the number of
    neighbours.  The rate is ``w' max(f_hat, 0) + (1 - w') max(m, 0)`` with
    ``w = MSE / (MSE + V_m)`` and ``w'`` its excess over a flat neighbourhood's
    (module notes: 0 there, so that the rate does not depend on the pixel's own
    noise); ``w`` rises to 1 where ``|f_hat - m|`` exceeds 3 to 5
    standard deviations (hot pixels, unresolved sources) and where fewer than 8
    neighbours are usable.

    Parameters
    ----------
    slope, var_read, pcoef : ndarray, shape (ny, nx), float32
        Fitted rate (e-/s), read variance ((e-/s)^2) and Poisson variance per unit
        rate ((e-/s)^2 per e-/s) of every pixel.
    usable : ndarray of bool, shape (ny, nx)
        Pixels whose rate may serve as a neighbour (measured, not reference).
    pool : concurrent.futures.Executor or None
        Runs chunks of pixels in parallel.

    Returns
    -------
    ndarray, shape (ny, nx), float32, e-/s, >= 0
    """
    return local_rates(slope, var_read, pcoef, usable=usable, pool=pool)[0]


def local_rates(slope, var_read, pcoef, *, usable, pool=None, own_share=True,
                need=None):
    """The variance rate of :func:`local_rate` and the rate of the GLS weights.

    The weight rate (module notes) leaves out the pixel's own rate where its
    neighbourhood is flat, and takes the neighbours' median shrunk toward 0 by the
    non-negative garrote (0 below two of its standard errors): weights are never
    evaluated at a rate that the pixel's own noise moved, and lean toward the
    read-noise weights where the neighbours cannot tell the rate from 0.  The
    variance rate also leaves out the own rate in a flat neighbourhood (module
    notes).  Arguments as in :func:`local_rate`;
    ``own_share=False`` leaves the own rate out of the weight rate everywhere (a
    first round, before the pixels' rates are efficient enough to tell a source
    from noise); ``need``, if given, is :func:`uses_neighbours` of the same
    arguments (computed otherwise).

    Returns
    -------
    variance_rate, weight_rate : ndarray, shape (ny, nx), float32, e-/s, >= 0
        Both the pixel's own rate clipped at 0 where :func:`uses_neighbours` is
        False.
    """
    ny, nx = slope.shape
    half = _LOCAL_HALF
    own = np.maximum(slope, _F32(0)).astype(_F32)
    if need is None:
        need = uses_neighbours(slope, var_read, pcoef, usable=usable)
    idx = np.flatnonzero(need)
    if idx.size == 0:
        return own, own.copy()
    wpad = nx + 2 * half
    pad = np.pad(np.where(usable, slope, np.nan).astype(_F32), half,
                 constant_values=np.nan).reshape(-1)
    offs = np.array([dy * wpad + dx for dy in range(-half, half + 1)
                     for dx in range(-half, half + 1) if (dy, dx) != (0, 0)], np.intp)
    base = (idx // nx + half) * wpad + idx % nx + half
    nnb = offs.size
    f_all, vr_all, pc_all = slope.reshape(-1), var_read.reshape(-1), pcoef.reshape(-1)
    out = own.reshape(-1).copy()
    outw = own.reshape(-1).copy()
    step = max(1, CHUNK_ELEMS // nnb)
    nmap = _usable_neighbours(usable, half)

    def work(c0):
        sel = idx[c0:c0 + step]
        stack = pad[base[c0:c0 + step, None] + offs[None, :]]     # (m, 24)
        stack.sort(axis=1)                                       # NaN (unusable) last
        out[sel], outw[sel] = _shrunk_rate(stack, nmap[sel], f_all[sel],
                                           vr_all[sel], pc_all[sel], own_share)

    starts = range(0, idx.size, step)
    if pool is None:
        for c0 in starts:
            work(c0)
    else:
        list(pool.map(work, starts))
    return out.reshape(ny, nx), outw.reshape(ny, nx)


def uses_neighbours(slope, var_read, pcoef, *, usable):
    """Pixels whose :func:`local_rate` is taken from their neighbourhood.

    Those where one standard deviation of the rate changes the variance by more
    than ``sqrt(3e-3)`` of itself (``kappa^2 = pcoef^2 / V >= 3e-3``, ``V`` at the
    pixel's own rate clipped at 0); elsewhere the own rate is as good (module
    notes).  Arguments as in :func:`local_rate`.

    Returns
    -------
    ndarray of bool, shape (ny, nx)
    """
    own = np.maximum(slope, _F32(0)).astype(_F32)
    vown = var_read + pcoef * own
    return usable & (pcoef * pcoef > _F32(_LOCAL_KAPPA2) * vown)


def _usable_neighbours(usable, half):
    """Usable neighbours of every pixel, flat (ny * nx,): box sum minus the centre."""
    ny, nx = usable.shape
    box = 2 * half + 1
    up = np.pad(usable.astype(np.int8), half)
    rows_sum = sum(up[:, k:k + nx] for k in range(box))          # (ny + 4, nx)
    return (sum(rows_sum[k:k + ny] for k in range(box)) - usable).reshape(-1)


def _quantile(flat, rowbase, start, n, p):
    """Linearly interpolated quantile ``p`` of sorted ``row[start:start + n]``."""
    pos = p * (np.maximum(n, 1) - 1).astype(_F32)
    i0 = pos.astype(np.intp)
    i1 = np.minimum(i0 + 1, np.maximum(n - 1, 0))
    a = flat[rowbase + start + i0]
    return a + (pos - i0) * (flat[rowbase + start + i1] - a)


def _shrunk_rate(stack, n, f, vr, pc, own_share=True):
    """Posterior-mean variance rate and weight rate of ``m`` pixels.

    ``stack`` (m, 24) float32 sorted neighbour rates (NaN last), ``n`` (m,) usable
    neighbours, ``f``/``vr``/``pc`` (m,) the pixels' rate, read variance and Poisson
    variance per unit rate.  Returns two (m,) float32 arrays, e-/s.
    """
    nnb = stack.shape[1]
    flat = stack.reshape(-1)
    rowbase = np.arange(stack.shape[0], dtype=np.intp) * nnb
    lo = np.zeros_like(n)
    with np.errstate(invalid="ignore", divide="ignore"):
        med = _quantile(flat, rowbase, lo, n, 0.5)
        q1 = _quantile(flat, rowbase, lo, n, 0.25)
        q3 = _quantile(flat, rowbase, lo, n, 0.75)
        # one clip at 4 robust sigma: isolated hot or hit neighbours out
        scale = _F32(_LOCAL_CLIP) * np.maximum(
            (q3 - q1) / _F32(_IQR_SIGMA),
            np.sqrt(vr + pc * np.maximum(np.nan_to_num(med), 0)))
        clip = (flat[rowbase] < med - scale) | (
            flat[rowbase + np.maximum(n - 1, 0)] > med + scale)
        if clip.any():
            c = np.flatnonzero(clip)
            sc = stack[c]
            lo_c = (sc < (med[c] - scale[c])[:, None]).sum(axis=1)
            n_c = (sc <= (med[c] + scale[c])[:, None]).sum(axis=1) - lo_c
            lo[c], n[c] = lo_c, n_c
            med[c] = _quantile(flat, rowbase[c], lo_c, n_c, 0.5)
            q1[c] = _quantile(flat, rowbase[c], lo_c, n_c, 0.25)
            q3[c] = _quantile(flat, rowbase[c], lo_c, n_c, 0.75)
        mpos = np.maximum(np.nan_to_num(med), _F32(0))
        v_m = vr + pc * mpos
        nn = np.maximum(n, 1).astype(_F32)
        spread = ((q3 - q1) / _F32(_IQR_SIGMA)) ** 2
        gate = v_m * (1 + _F32(2 * _IQR_VAR) / np.sqrt(nn))
        mse = np.maximum(spread - gate, 0) + _F32(math.pi / 2) * v_m / nn
        w = mse / np.maximum(mse + v_m, _F32(TINY))
        dev = np.abs(f - med) / np.sqrt(np.maximum(v_m + mse, _F32(TINY)))
        w = np.maximum(w, np.clip((dev - _F32(3)) / _F32(2), 0, 1))
        w = np.where((n >= _LOCAL_MIN) & np.isfinite(w), w, _F32(1))
        # weight rate: the own share beyond that of a flat neighbourhood, and the
        # neighbours' median shrunk toward 0 by _WEIGHT_LOWER of its errors
        c = _F32(math.pi / 2) / nn
        w_flat = c / (1 + c)
        wx = np.clip((w - w_flat) / (1 - w_flat), 0, 1) * _F32(own_share)
        # non-negative garrote: 0 below k standard errors, -> the median far above
        k2mse = _F32(_WEIGHT_LOWER ** 2) * mse
        mz = np.nan_to_num(med)
        low = np.where(mz * mz > k2mse, mz - k2mse / np.where(mz > 0, mz, 1), 0)
        low = np.where(np.isfinite(low) & (mz > 0), low, 0)
    fpos = np.maximum(f, _F32(0))
    wv = np.clip((w - w_flat) / (1 - w_flat), 0, 1)
    return (wv * fpos + (1 - wv) * mpos).astype(_F32), \
        (wx * fpos + (1 - wx) * low).astype(_F32)
