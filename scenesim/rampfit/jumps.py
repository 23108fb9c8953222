"""Jump (cosmic-ray) detection in up-the-ramp rate estimates.

Statistic
---------
For the model ``d = f 1 + J s + noise`` of the rate estimates of one integration
(covariance ``C`` at rate ``f``, :mod:`scenesim.rampfit.covariance`), the
standardised score statistic for a jump of signature ``s`` is::

    z = s^T C^-1 r / sqrt(s^T C^-1 s - (s^T C^-1 1)^2 / (1^T C^-1 1)),

``r = d - f_hat 1`` the GLS residuals (:func:`jump_statistics`).  Without a jump it
is exactly N(0, 1) for Gaussian noise whatever the readout, so a (one-sided)
threshold ``k`` gives ``Q(k)`` false alarms per test at the true rate.  With the
covariance at the clipped mean (below) it gives more where read noise dominates:
1.3-1.5 ``Q(k)`` at 0.3-3 e-/s, 10 e- read noise, RAPID x 10, k = 4 (a probe,
docs/VALIDATION_FIT.md); ``Q(k)`` from 10 e-/s up.  A single difference ``i`` has ``s = e_i``;
a hit halfway through a multi-read resultant ``R_{i+1}`` adds half its charge to
``D_i`` and half to ``D_{i+1}``: ``s = e_i / dt_i + e_{i+1} / dt_{i+1}``.

Procedure (:func:`flag_jumps`, threshold in sigma, per integration)
--------------------------------------------------------------------
The covariance is taken at the mean of the usable differences that lie within 3 of
their standard deviations of the median (a clipped mean, :func:`_clipped_mean`;
the standard deviations at the larger of the median and the mean without the
largest and the smallest difference, :func:`_robust_rates`), robust to hits and
nearly as precise as the mean of a clean ramp.  The rate matters more than it
looks: in a read-noise dominated ramp it sets how much of the ramp's smooth wander
the model grants the Poisson charge, and a step (a hit) is told from that wander.
Taken too low (the median, 0 in a photon-counting ramp of fewer than ~0.7 e- per
difference; or the mean without the largest, biased low by E[max] / nd) the
statistics inflate: every electron was a jump (10 e-/s on 18 ms frames, no read
noise: 100 % of pixels, slope -0.1 e-/s), and 2000 RAPID differences at 0.01 e- per
read put 82 of 256 clean pixels over 5 sigma.  Taken too high (a margin of twice
its error, tried on 2026-11-27 and dropped) the test loses power: a 25 e- hit in
RAPID x 60 at 0.2 e-/s and 6 e- read noise was caught in 54 % of pixels instead of
95 %.  Long ramps are sensitive to the rate's own error (the clipped mean alone:
22-33 of 256 clean pixels over 5 sigma at 2000 differences), so from
:data:`_MARGIN_DIFFS` = 50 differences on the rate is taken one standard error
above it, ``sqrt(1^T C 1 + m alpha) / nd`` for ``m`` differences left out.
Measured with this rule (3 seeds or 4096-65536 pixels each): 0-1 of 256 clean
pixels at 500-2000 differences; RAPID x 60 catches 96 % of 25 e- hits, with 39
false alarms at 3.5 sigma for the 56 expected; RAPID x 10 (10.7 s frames, 6 e-
read noise, 0.2 e-/s, 4096 pixels) 33 % of 35 e- hits (30 % before), 10 false
alarms for 8.6; photon counting at 0.18 and
0.6 e- per difference: none.  Still below the old median rule: 35 e- hits in
MEDIUM8 x 10 (13 % caught against 20 %) and in a Roman-like table (49 % against
53 %), where the old rule was also 1.5x too liberal.

Every usable difference, and every pair sharing a multi-read resultant, gets its
statistic, less an allowance for the skewness ``gamma`` of Poisson charge: by the
Cornish-Fisher expansion a clean statistic reaches ``k + (k**2 - 1) gamma /
6`` as often as a Gaussian one reaches ``k``, so ``(k**2 - 1) gamma / 6`` is taken
off (``gamma = f Ap_i**2 / a_i**1.5`` for a difference of variance ``a_i``, exact
for single reads; :func:`_skew_allowance`).  Where read noise dominates it is
negligible (0.08 sigma at 100 e- per difference and 10 e- read noise, k = 5); with
no read noise it is ``(k**2 - 1) / 6`` = 4 e- at k = 5, so that a clean difference
of 0.18 e- mean needs >= 5 e- to be flagged (P = 1.6e-6) instead of one electron.
The largest *positive* excess above the threshold is flagged and excluded (a pair
as a whole when it is the larger), and the test repeated on the pixels that had a
flag.  The test is one-sided because a hit adds charge: a hit raises the common
rate, so the clean differences read low, and with few differences a two-sided test
would as often exclude the clean half of a ramp as the hit one (with two usable
differences their residuals are exactly opposite).  Detection needs >= 2 usable
differences (no pair when only two are left: it would be the whole ramp).
Excluding a difference splits the ramp into independent segments.

Drops.  Charge can also fall: a telegraph pixel steps down, a resultant spikes up
and the next difference reads the fall.  A drop pulls the common rate down, and the
one-sided test then read the *clean* differences high, flagged them one by one and
kept the drop (a probe, 2026-11-28: a 300 e- step down in RAPID x 10 at 1 e-/s and
10 e- read noise gave 8 flags of 9 differences, slope -28 e-/s; without detection
-3.6; a one-resultant spike of 1000 e-: -99 e-/s).  So where a pass would flag a
positive statistic, the strongest negative single difference takes the flag
instead when its ``|z|`` is more than :data:`_DROP_RATIO` times larger: one drop
among ``n`` differences reads about ``n - 1`` times the clean ones it pushes up,
while two hits read about as high as the clean differences they push down (the
ratio 1 in the limit; 1.5 leaves every seeded two-hit case of the tests as it
was).  A drop alone, with no clean difference pushed over the threshold, is left
in: the false-alarm rate of clean ramps is unchanged, ``Q(k)`` per test.  With
fewer than 4 usable differences one drop and hits in all the others look alike
(ratio 2 both ways), and hits are kept the likelier.  The ratio is taken against
the largest positive *single* difference (a pair of clean differences pushed up
reads ~sqrt(2) times one), and a pixel with a dominant drop beyond the threshold
gets no look-ahead (leaving out a clean difference would push the others higher
still), and the drop takes the flag only where the differences left without it
are consistent (no ``|z|`` of either sign above the threshold) and more so than
without the positive span (:func:`_drop_fits_better`: in DEEP8 x 5 a hit inside
group 1, split between two differences, and one before the last group leave one
clean difference that reads like a drop; the dominance test alone took it in 1 %
of such pixels).  After the change the probe's step reads 0.99 e-/s (1 flag), the spike
1.01 (2 flags); on 10^4-pixel sweeps of 50-500 e- drops at 0.5 and 20 e-/s
(``tests/tools/jump_drops.py``) mean ``z^2`` fell from 270-5400 to 5-42 in RAPID x
10, 6 groups x 4 frames and the Roman table, of spikes from 210-5000 to 1.0-190;
clean ramps and single hits are as before, RAPID x 4 (3 differences) unchanged.
**The price** (a regression probe, 2026-11-28): two hits that both arrive *inside*
multi-frame groups each raise two differences, and in a short ramp they can leave
one clean difference that reads like a drop, which then takes the flag and leaves
the hits in (6 groups x 4 frames, 0.5 e-/s, 10 e-: hits inside groups 1 and 4, 351
and 489 e-, noiseless: slope 4.59 e-/s for 0.5).  Over 10^4 pixels of two 50-500
e- hits at random times, mean ``z^2`` 4.5 -> 8.4 (6 x 4 frames), 7.9 -> 14.0 (5 x 8
frames, gap 4), 1.89 -> 1.93 (Roman), unchanged in RAPID; drops and spikes there
gained 1850 -> 12, 3700 -> 3.2, 2100 -> 8.  Comparing the drop with the pairs'
statistics too halves the two-hit cost and a third to a fifth of the drop gain
(4.5 -> 6.5; drops 64, 40); it is not taken: two hits in one pixel and integration
are rarer than telegraph pixels' steps (at ~5 cosmic rays per cm^2 and second,
1e-4-1e-3 of 18 um pixels are hit twice in 1000 s, counting the few pixels a hit
spreads over; telegraph pixels are reported at the 0.1-few % level and step in most
integrations).  ``tests/tools/jump_drops.py`` puts hits at resultant boundaries;
split hits need ``fraction of reads after the hit`` per resultant.  What is left: a drop that
pushes no clean difference over the threshold stays in, as it did without
detection (a 300 e- step in the Roman table: 227 of 4096 pixels unflagged, mean
``z^2`` 2.5), and a spike in one resultant of multi-read groups still costs many
pixels their last difference (6 groups x 4 frames at 0.5 e-/s: 3955 of 10^4).

What a flag costs.  A hit adds its charge to every read after it, so it moves only
the resultant during which it arrived (by the fraction of that resultant's reads
after it) relative to the line through the others: the differences touching that
resultant are the part of the ramp it touches.

* A flagged pair (a hit inside the multi-read resultant the two differences share)
  costs those two differences only: the resultants on either side are untouched.
* A flagged single difference may hold a hit that arrived during a multi-read
  resultant at either end of it (a small remainder then sits in the neighbour
  sharing that resultant, below the pair's statistic); the neighbours sharing a
  multi-read resultant are excluded too, unconditionally (choosing them by their
  values would bias the slope), but only once the detection has ended: until
  then they stay in the test as the clean reference of the other hits (a
  remainder above the threshold is flagged like any hit).  Excluding them at
  once lost that reference: in 5-group MEDIUM8/DEEP8 ramps with a hit in the gap
  before the last group and another inside group 1 (its charge split between the
  first two differences), the second was left in the two differences that
  remained, undetectable (8 % of such DEEP8 pixels kept a 100 sigma hit;
  ``docs/STRESS.md``).  If excluding the neighbours would leave no usable
  difference of the integration, they all stay.  A hit never costs a pixel with
  usable differences.  With
  single-read resultants (JWST NFRAMES=1) neither the pairs nor the neighbours
  apply.

What the skewness allowance costs: where Poisson charge dominates multi-read
differences, their tail at 5 sigma is several times the Gaussian one (Poisson of
30 e-: ~10x), and the allowance (~0.7 sigma there) moves the effective threshold to
match; a hit that another one masks then falls below it more often.  In
``docs/STRESS.md`` (2026-11-27) two 10 sigma_d hits in ROMANSKIP6 at 1 e-/s and 1
e- read noise are both caught in 0.61 of the pixels (0.63 before the allowance and
the clipped mean), and the ones that stay 10 sigma in 0.9945 (0.9991).  It is kept:
without it a 5 sigma test of such differences is ~10x too liberal, and of
photon-counting ones 100 % so.

Known limits (measured by a probe, 2026-11-27, not fixed).  With 3 usable
differences of multi-read groups, a hit inside a group puts half its charge into
two of the three: the median and the trimmed mean both take the hit's rate, the
covariance is taken ~90x too high, and a 50 e- hit at 0.3 e- per read (4 groups x
NFRAMES 8, read noise 0-5 e-) is flagged in < 1 % of pixels (slope 7.5x too high);
200 e- is always flagged, and from 6 groups on 50 e- is.  In photon-counting ramps
of multi-read groups (read noise 0, 0.2 e- per read, 5 groups x NFRAMES 4) the
skewness allowance, exact for single reads only, leaves 5.6e-4 false pixels where
the tests give 2e-6.

Two hits mask each other: each raises the common rate of the other's test (in a
10-group RAPID ramp two 10 sigma hits far apart both read ~5.3 sigma).  A pixel with
no statistic above the threshold but one above half of it is therefore tested again
with that span left out (look-ahead), and the strongest span of that test is flagged
if it now exceeds the threshold; the first span is then tested in the next pass with
the second left out.  A false alarm still needs a statistic above the threshold, so
the false-alarm rate stays ``~Q(k)`` per test.

Where the read noise is 0 the covariance uses a rate of at least
:data:`scenesim.rampfit.covariance.RATE_FLOOR`.  (Before the mean and the skewness
allowance, a 64 x 64 x 100 RAPID scene of 10 e-/s with no read noise and 18 ms frames
had 100 % of its pixels flagged and slopes of -0.1 e-/s; now none, and the slopes are
unbiased.  Their cost in time is in BENCHMARKS.md.)  The first pass runs in blocks of
4096 pixels, which keeps the (n_diff, pixels) work arrays in cache; the later passes
and the look-aheads, on the few pixels that need them, run on all the caller's pixels
at once (per block they cost ~0.4 ms of numpy overhead each; at once, a 512 x 512 x 20
RAPID fit with jump detection went from 0.45 to 0.40 s).  On two or more threads the
first pass takes longer blocks (:func:`jump_block`). """

import numpy as np

from scenesim.rampfit.covariance import RATE_FLOOR
from scenesim.rampfit.solver import TINY

__all__ = ["flag_jumps", "jump_block", "jump_statistics"]

_F32 = np.float32
_JUMP_BLOCK = 4096
#: On two or more threads the first pass takes blocks of up to this many pixels, at
#: most :data:`_JUMP_VALUES` differences: its numpy calls on 4096 pixels last 1-2 us,
#: and between calls the threads queued for the GIL (2048^2 x 20 GLS with jumps, two
#: threads: 2.01-2.02 s with 4096-pixel blocks, 1.66-1.72 s with 65536; one thread
#: 2.67-2.77 s whatever the block; at 1024^2 x 100 one thread is 13 % slower with
#: 16384-pixel blocks, whose arrays leave the cache, so it keeps 4096).
_JUMP_BLOCK_THREADED = 65536
_JUMP_VALUES = 1 << 20


def jump_block(n_diff, threads=1):
    """Pixels per block of the first detection pass for ``n_diff`` differences
    per pixel on ``threads`` threads (see :data:`_JUMP_BLOCK_THREADED`)."""
    if threads <= 1:
        return _JUMP_BLOCK
    return max(_JUMP_BLOCK, min(_JUMP_BLOCK_THREADED, _JUMP_VALUES // max(1, n_diff)))


#: Pixels whose strongest statistic exceeds this fraction of the threshold get the
#: look-ahead test for two hits masking each other (module notes).
_LOOKAHEAD = 0.5
#: A drop takes the flag of a pass from a positive statistic above the threshold
#: when its ``|z|`` is this many times larger (module notes: one drop reads ~(n -
#: 1) times the clean differences it pushes up, two hits ~1 times the clean ones).
_DROP_RATIO = 1.5


def flag_jumps(d, valid, s2, cov, threshold, *, block=_JUMP_BLOCK):
    """Flag jumps in every integration; ``valid`` is updated in place.

    Parameters
    ----------
    d : ndarray, shape (nints, nd, P), float32, e-/s
        Rate estimates of ``P`` pixels.
    valid : ndarray of bool, shape (nints, nd, P)
        Usable differences; flagged ones are set False.
    s2 : float or ndarray (P,) float32
        Read variance of one read, e-^2.
    cov : scenesim.rampfit.covariance.RampCovariance
    threshold : float
        Detection threshold, sigma (> 0).
    block : int, keyword-only
        Pixels per block of the first pass (:func:`jump_block`); the flags do not
        depend on it.

    Returns
    -------
    ndarray, shape (P,), int32
        Number of flagged differences per pixel (all integrations).
    """
    nints, _, npix = d.shape
    counts = np.zeros(npix, np.int32)
    for k in range(nints):
        counts += _detect_jumps(d[k], valid[k], s2, cov, threshold, block).sum(
            axis=0, dtype=np.int32)
    return counts


def _detect_jumps(d, valid, s2, cov, thr, block):
    """Flag jumps in one integration; ``valid`` (nd, P) is updated in place.

    Returns the (nd, P) bool array of flagged differences (module notes).
    """
    nd, npix = d.shape
    jumps = np.zeros((nd, npix), bool)
    nbr = np.zeros((nd, npix), bool)                   # neighbours, excluded at the end
    multi = cov.n > 1                                  # multi-read resultants
    idx = np.flatnonzero(valid.sum(axis=0) >= 2)
    for _ in range(nd - 1):
        if idx.size == 0:
            break
        zmax, first, last, pair, down, zdown = _strongest_blocks(
            d, valid[:, idx], s2, idx, cov, thr, block)
        hit = zmax > thr
        # A drop (a telegraph pixel's step down, the second half of a spike in one
        # resultant) pulls the common rate down and the clean differences read
        # high: where a pass would flag one of them, a stronger drop takes the flag
        # instead (module notes)
        drop = hit & (zdown > 0)
        if drop.any():
            drop[drop] = _drop_fits_better(d, valid, s2, idx[drop], cov, thr,
                                           down[drop], first[drop], last[drop])
        first[drop] = last[drop] = down[drop]
        pair[drop] = False
        # Look-ahead: two hits can mask each other (each pulls the common rate
        # toward itself); a pixel whose strongest statistic is within a factor
        # _LOOKAHEAD of the threshold is tested again without that span, and the
        # strongest span of that test is flagged if it now exceeds the threshold.
        # (not where a drop beyond the threshold dominates: leaving out a clean
        # difference it pushed up would push the others higher still)
        look = ~hit & (zmax > _LOOKAHEAD * thr) & (valid[:, idx].sum(axis=0) >= 3) \
            & ~(zdown > thr)
        if look.any():
            il = idx[look]
            vt = valid[:, il].copy()
            rows = np.arange(nd)[:, None]
            vt &= ~((rows >= first[look]) & (rows <= last[look]))
            z2, f2, l2, p2, _, _ = _strongest_blocks(d, vt, s2, il, cov, thr, block)
            ok = z2 > thr
            sel = np.flatnonzero(look)[ok]
            hit[sel] = True
            first[sel], last[sel], pair[sel] = f2[ok], l2[ok], p2[ok]
        ih = idx[hit]
        _exclude(jumps, nbr, valid, ih, first[hit], last[hit], pair[hit], multi)
        idx = ih[valid[:, ih].sum(axis=0) >= 2]
    # the neighbours of flagged single differences: out, unless no usable
    # difference of the integration would be left (then they all stay)
    cols = np.flatnonzero(nbr.any(axis=0)) if multi.any() else ()
    if len(cols):
        vc = valid[:, cols]
        nc = nbr[:, cols] & vc
        rest = vc & ~nc
        sel = cols[rest.sum(axis=0) >= 1]
        keep = rest.sum(axis=0) >= 1
        jumps[:, sel] |= nc[:, keep]
        valid[:, sel] = rest[:, keep]
    return jumps


def _drop_fits_better(d, valid, s2, ic, cov, thr, down, first, last):
    """Of the pixels ``ic`` with a dominant drop at ``down`` and a positive span
    ``first..last`` over the threshold: those whose remaining differences are
    consistent (no ``|z|`` of either sign above the threshold) with the drop left
    out, and more so than with the span left out.  A drop is one difference; hits inside
    multi-read groups touch two each, and two of them can leave the one clean
    difference of a short ramp reading like a drop (DEEP8 x 5 with a hit inside
    group 1 and one before the last group: the dominance test alone took the clean
    difference in 1 % of the pixels)."""
    nd = d.shape[0]
    cols = np.arange(ic.size)
    rows = np.arange(nd)[:, None]
    va = valid[:, ic].copy()
    va[down, cols] = False
    vb = valid[:, ic] & ~((rows >= first) & (rows <= last))
    za = _strongest(d[:, ic], va, s2, ic, cov, thr, raw=True)
    zb = _strongest(d[:, ic], vb, s2, ic, cov, thr, raw=True)
    worst_a = np.maximum(za[0], za[5])
    return (worst_a <= thr) & (worst_a < np.maximum(zb[0], zb[5]))


def _strongest_blocks(d, vv, s2, idx, cov, thr, block):
    """:func:`_strongest` of the pixels ``idx`` (usable differences ``vv``, (nd,
    len(idx))) in blocks of ``block`` pixels (:func:`jump_block`), which keep the
    work arrays in cache; the later passes and look-aheads, on few pixels, run in
    one call."""
    if idx.size <= block:
        return _strongest(d[:, idx], vv, s2, idx, cov, thr)
    parts = [_strongest(d[:, idx[c:c + block]], vv[:, c:c + block], s2,
                        idx[c:c + block], cov, thr)
             for c in range(0, idx.size, block)]
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(6))


def _strongest(dd, vv, s2, idx, cov, thr, raw=False):
    """Largest positive statistic of each pixel and its span: (zmax, first, last,
    pair), the statistics less their skewness allowance (:func:`_skew_allowance`),
    and the strongest drop (down, zdown): the most negative single difference and
    its ``|z|``, 0 where it does not dominate the positive single differences
    (:data:`_DROP_RATIO`) or with fewer than 4 usable differences (``raw``: the
    ``|z|`` of the most negative single difference whatever they are).  With only
    two usable differences a pair would be the whole ramp, so only single
    differences are tested.
    """
    med, rest = _robust_rates(dd, vv)
    s2i = s2 if np.isscalar(s2) else s2[idx]
    lo = _F32(RATE_FLOOR) * (s2i == 0)
    f, left_out = _clipped_mean(dd, vv, med, np.maximum(np.maximum(med, rest), lo),
                                s2i, cov, lo)
    nd = dd.shape[0]
    if nd >= _MARGIN_DIFFS:
        # the standard error of the clipped mean above it (module notes): that of
        # the mean of all differences, sqrt(1^T C 1) / nd (read noise telescopes out
        # of their sum), plus a difference's variance for each one left out (which
        # breaks the telescoping)
        c11 = (s2i * _F32(cov.Ar.sum() + 2 * cov.Br.sum())
               + f * _F32(cov.Ap.sum() + 2 * cov.Bp.sum())
               + left_out * (s2i * _F32(cov.Ar.mean()) + f * _F32(cov.Ap.mean())))
        if cov.has_q:
            c11 += (_F32(cov.Aq.sum() + 2 * cov.Bq.sum())
                    + left_out * _F32(cov.Aq.mean()))
        f = f + _F32(1.0 / nd) * np.sqrt(np.maximum(c11, _F32(0)))
    z, zp = _signed_statistics(dd, vv, med, s2i, f, cov)
    gz, gp = _skew_allowance(s2i, f, cov, thr)
    # the strongest drop (negative single difference), for _detect_jumps; with
    # fewer than 4 usable differences a drop cannot be told from hits in all the
    # others (module notes): none there
    down = z.argmin(axis=0)
    zdown = np.maximum(-z[down, np.arange(z.shape[1])], 0)
    if not raw:
        zdown[vv.sum(axis=0) < 4] = 0
    z -= gz
    np.maximum(z, 0, out=z)
    if zp is not None:
        zp = np.where(vv.sum(axis=0) == 2, 0, np.maximum(zp - gp, 0))
    # a drop dominates when its |z| is _DROP_RATIO times the largest positive single
    # difference's (a pair of clean differences a drop pushed up reads ~sqrt(2)
    # times one of them, so not the pairs)
    if not raw:
        zdown[zdown <= _F32(_DROP_RATIO) * z.max(axis=0)] = 0
    return _largest_excess(z, zp) + (down, zdown)


def _skew_allowance(s2, f, cov, thr):
    """How far above ``thr`` the statistics of a clean ramp reach by the skewness of
    its Poisson charge: ``(thr**2 - 1) / 6 * gamma`` (Cornish-Fisher), ``gamma`` the
    skewness of a difference (``f Ap_i**2 / a_i**1.5``: exact for single-read
    resultants, where ``d_i = N / dt_i``, ``N`` Poisson) or of the two of a pair.

    Returns ``(gz (nd, n), gp (nd - 1, n) or None)``, float32."""
    c = _F32(max(thr * thr - 1.0, 0.0) / 6.0)
    ap = cov.Ap.astype(_F32)[:, None]
    a = s2 * cov.Ar.astype(_F32)[:, None] + f * ap
    if cov.has_q:
        a += cov.Aq.astype(_F32)[:, None]
    a = np.maximum(a, _F32(TINY))
    k3 = (c * ap * ap) * f
    gz = k3 / (a * np.sqrt(a))
    gp = None
    if (cov.n > 1).any() and len(a) > 1:
        a2 = a[:-1] + a[1:]
        gp = (k3[:-1] + k3[1:]) / (a2 * np.sqrt(a2))
    return gz, gp


def _exclude(jumps, nbr, valid, ih, a, b, pair, multi):
    """Exclude the flagged spans ``a..b`` of pixels ``ih``; mark their neighbours.

    A pair (a hit inside the multi-read resultant the two differences share)
    costs those two differences only.  A single difference ``i`` may hold a hit
    that arrived during a multi-read resultant at either end of it, leaving a
    remainder in the neighbour sharing that resultant: the neighbour is marked in
    ``nbr`` (whatever its value: a choice by its value would bias the slope) and
    stays in the detection, where it is the clean reference of the next passes
    (or is flagged itself if its remainder exceeds the threshold);
    :func:`_detect_jumps` excludes the marked neighbours at the end.
    """
    nd = valid.shape[0]
    for pos in (a, b):
        jumps[pos, ih] |= valid[pos, ih]
        valid[pos, ih] = False
    single = ~pair
    left = single & (a >= 1) & multi[a]
    right = single & (b + 1 < nd) & multi[np.minimum(b + 1, nd - 1)]
    pl, pr = np.maximum(a - 1, 0), np.minimum(b + 1, nd - 1)
    nbr[pl[left], ih[left]] = True
    nbr[pr[right], ih[right]] = True


def _clipped_mean(d, valid, med, f0, s2, cov, lo):
    """The covariance rate of the test (module notes): the mean of the usable
    differences within :data:`_CLIP` of their own standard deviations (at the rate
    ``f0``) of the median, or ``f0`` where none is; at least ``lo``.  Also returns
    how many usable differences were left out (float32)."""
    a = f0 * (_F32(_CLIP ** 2) * cov.Ap.astype(_F32)[:, None])
    a += s2 * (_F32(_CLIP ** 2) * cov.Ar.astype(_F32)[:, None])
    if cov.has_q:
        a += _F32(_CLIP ** 2) * cov.Aq.astype(_F32)[:, None]
    dev = d - med
    dev *= dev
    keep = dev <= a                       # (d - med)^2 <= CLIP^2 alpha
    keep &= valid
    nk = keep.sum(axis=0)
    tot = (d * keep).sum(axis=0, dtype=np.float64)
    mean = np.where(nk > 0, tot / np.maximum(nk, 1), f0).astype(_F32)
    return np.maximum(mean, lo), (valid.sum(axis=0) - nk).astype(_F32)


#: From this many differences per integration on, the covariance rate is taken one
#: standard error above the clipped mean (module notes).
_MARGIN_DIFFS = 50
#: Differences further than this many of their standard deviations from the median
#: are left out of the covariance rate (:func:`_clipped_mean`): symmetric, so the
#: noise of a clean ramp leaves the mean unbiased (0.27 % of Gaussian differences),
#: and low enough that a hit just above the detection threshold, which would raise
#: the rate and hide itself, is left out too (5 sigma kept 35 e- hits in RAPID x 10
#: at 5.2 e- read noise, 0.2 e-/s, one hit at a random read of 4096 pixels: caught
#: in 49 % of pixels; 3 sigma: 62 %, 59 % before).
_CLIP = 3.0


def _robust_rates(d, valid):
    """Median over the usable differences of every pixel, and their mean without
    the largest and the smallest (without the largest only, with 2 usable), both
    (n,) float32.  The second is robust to one hit, does not drop to 0 where most
    differences hold no electron (as the median does), and is unbiased for
    symmetric noise (leaving out the largest alone biased it low by E[max] / n:
    -0.013 e-/s in 2000 RAPID differences of 7.4 e-/s noise, below a true 0.01,
    and a covariance at rate 0 there understates the smooth components of the
    ramp, which the Poisson charge dominates, so clean differences read 10-15
    sigma; module notes)."""
    srt = np.where(valid, d, np.inf).T.copy()
    srt.sort(axis=1)
    n = valid.sum(axis=0)
    lo = np.take_along_axis(srt, ((n - 1) // 2)[:, None], axis=1)[:, 0]
    hi = np.take_along_axis(srt, (n // 2)[:, None], axis=1)[:, 0]
    top = np.take_along_axis(srt, np.maximum(n - 1, 0)[:, None], axis=1)[:, 0]
    low = np.where(n >= 3, srt[:, 0], 0.0)
    tot = np.where(valid, d, _F32(0)).sum(axis=0, dtype=np.float64)
    rest = np.where(n >= 2, (tot - top - low) / np.maximum(n - 1 - (n >= 3), 1),
                    -np.inf)
    return _F32(0.5) * (lo + hi), rest.astype(_F32)


def _largest_excess(z, zp):
    """Largest statistic of every pixel and its span of differences.

    Returns (zmax (n,), first (n,), last (n,), pair (n,) bool): the span of each
    pixel's largest statistic (one difference, or a pair).
    """
    cols = np.arange(z.shape[1])
    first = z.argmax(axis=0)
    zmax = z[first, cols]
    last = first.copy()
    pair = np.zeros(z.shape[1], bool)
    if zp is not None:
        q = zp.argmax(axis=0)
        zq = zp[q, cols]
        pair = zq > zmax
        first = np.where(pair, q, first)
        last = np.where(pair, q + 1, last)
        zmax = np.where(pair, zq, zmax)
    return zmax, first, last, pair


def jump_statistics(d, valid, fref, s2, f, cov):
    """GLS outlier statistics for a jump in each difference and each shared pair.

    The standardised score statistic of the module notes, for single differences
    (``s = e_i``) and for pairs sharing a multi-read resultant
    (``s = e_i / dt_i + e_{i+1} / dt_{i+1}``).  It uses
    ``(C^-1)_ii = 1/(delta_i + eta_i - a_i)`` with forward and backward pivots
    ``delta``, ``eta``, and ``(C^-1)_{i,i+1} = -b_i (C^-1)_{i+1,i+1} / delta_i``.

    Parameters
    ----------
    d : ndarray, shape (nd, n), float32, e-/s
        Rate estimates of one integration.
    valid : ndarray of bool, shape (nd, n)
        Usable differences.
    fref : ndarray, shape (n,), float32, e-/s
        Reference rate subtracted before the solves (e.g. the median of ``d``).
    s2 : float or ndarray (n,) float32
        Read variance of one read, e-^2.
    f : ndarray, shape (n,), float32, e-/s
        Rate of the covariance.
    cov : scenesim.rampfit.covariance.RampCovariance

    Returns
    -------
    z : ndarray, shape (nd, n), float32
        ``|z|`` of every single difference; 0 where a difference is not usable.
    zp : ndarray, shape (nd - 1, n), float32, or None
        ``|z|`` of every pair, or None when no pair shares a multi-read resultant.
    """
    z, zp = _signed_statistics(d, valid, fref, s2, f, cov)
    return np.abs(z), (None if zp is None else np.abs(zp))


def _signed_statistics(d, valid, fref, s2, f, cov):
    """:func:`jump_statistics` with signs (positive: charge added)."""
    nd, npix = d.shape
    mf = valid.astype(_F32)
    a = np.empty((nd, npix), _F32)
    for i in range(nd):
        ai = s2 * float(cov.Ar[i]) + f * float(cov.Ap[i])
        if cov.has_q:
            ai = ai + float(cov.Aq[i])
        a[i] = np.where(valid[i], ai, _F32(1))
    np.maximum(a, _F32(TINY), out=a)
    b = np.empty((max(nd - 1, 0), npix), _F32)
    for i in range(nd - 1):
        bi = s2 * float(cov.Br[i]) + f * float(cov.Bp[i])
        if cov.has_q:
            bi = bi + float(cov.Bq[i])
        b[i] = bi * mf[i] * mf[i + 1]
    y = (d - fref) * mf
    # forward pivots, L, and forward solves for 1 and y
    delta = np.empty_like(a)
    ell = np.zeros_like(a)
    zu = np.empty_like(a)
    zv = np.empty_like(a)
    S11 = np.zeros(npix, _F32)
    S1y = np.zeros(npix, _F32)
    for i in range(nd):
        if i == 0:
            delta[0], u, v = a[0], mf[0], y[0]
        else:
            ell[i] = b[i - 1] / delta[i - 1]
            delta[i] = a[i] - ell[i] * b[i - 1]
            u = mf[i] - ell[i] * u
            v = y[i] - ell[i] * v
        zu[i] = u / delta[i]
        zv[i] = v / delta[i]
        S11 += u * zu[i]
        S1y += v * zu[i]
    for i in range(nd - 2, -1, -1):                    # back substitution
        zu[i] -= ell[i + 1] * zu[i + 1]
        zv[i] -= ell[i + 1] * zv[i + 1]
    h = zu                                               # C^-1 1
    shift = np.divide(S1y, S11, out=np.zeros(npix, _F32), where=S11 > 0)
    g = zv - shift * h                                   # C^-1 r
    eta = np.empty_like(a)
    eta[nd - 1] = a[nd - 1]
    for i in range(nd - 2, -1, -1):
        eta[i] = a[i] - b[i] * b[i] / eta[i + 1]
    xd = _F32(1) / (delta + eta - a)                     # diag of C^-1
    inv11 = np.divide(1, S11, out=np.zeros(npix, _F32), where=S11 > 0)
    den = np.maximum(xd - h * h * inv11, _F32(TINY))
    z = g * mf / np.sqrt(den)
    pair_ok = cov.n[1:-1] > 1
    if nd < 2 or not pair_ok.any():
        return z, None
    zp = _pair_statistics(g, h, xd, b, delta, inv11, mf, pair_ok, cov)
    return z, zp


def _pair_statistics(g, h, xd, b, delta, inv11, mf, pair_ok, cov):
    """Signed ``z`` of the pairs (nd - 1, n) from the pieces of :func:`jump_statistics`."""
    xo = -b * xd[1:] / delta[:-1]                        # (C^-1)_{i,i+1}
    s0 = (1 / cov.dt[:-1]).astype(_F32)[:, None]
    s1 = (1 / cov.dt[1:]).astype(_F32)[:, None]
    num = s0 * g[:-1] + s1 * g[1:]
    sh = s0 * h[:-1] + s1 * h[1:]
    den_p = s0 * s0 * xd[:-1] + 2 * s0 * s1 * xo + s1 * s1 * xd[1:] - sh * sh * inv11
    ok = mf[:-1] * mf[1:] * pair_ok[:, None]
    return num * ok / np.sqrt(np.maximum(den_p, _F32(TINY)))
