"""Saturation flags judged from the ramps alone, as a pipeline without a reference file.

The forward effect (a pixel holds at most ``full_well`` electrons) is
:mod:`scenesim.detector.saturation`; this module finds where it happened in
recorded resultants (in e-, nothing subtracted).

Why a level test is not enough
------------------------------
A pixel at full well does not read ``full_well`` above its zero level: the
classical nonlinearity lowers it to ``p(FW)`` (7.7 % lower for ``c2 = -8e-7,
c3 = -2e-12`` at 8e4 e-), and IPC moves ``4 alpha + 4 alpha_diag`` of it into
neighbours that hold less (6 % for ``alpha = 1.5 %``), so a level test alone either
misses saturated pixels or, with a threshold low enough for every IPC kernel, flags
bright unsaturated ones.  A pixel saturated before its second resultant has a flat
first difference, which puts a naive zero level on its plateau.

Tests (:func:`saturation_flags`; a resultant is saturated when any says so)
-----------------------------------------------------------------------------
1. **ADC ceiling**: the estimated last read (below) is at the ceiling.
2. **Level**: the estimated last read is at least ``fraction * p(FW)`` above the
   zero level, ``p`` the nonlinearity (identity when ``None``): ``p(FW)`` is the
   most any pixel can read, IPC included (IPC averages neighbours that all hold at
   most FW), so ``fraction`` keeps its meaning of "within 3 % of full".
3. **Flattening**: the estimated last read is at least ``floor * p(FW)`` above the
   zero level, and the increment ``D_i`` of the linearised ramp (``p`` inverted)
   over the previous resultant falls below the increment expected from the ramp's
   earlier rate, ``f_i dt_i``, by more than both ``nsigma`` standard deviations and
   half of it::

       f_i dt_i - D_i > max(nsigma * s_i, f_i dt_i / 2),
       s_i^2 = read_noise^2 (1/N_{i-1} + 1/N_i) + max(f_i, 0) dt_i,

   with ``f_i`` the median of the (up to 16) previous rate estimates (the first one
   is the charge of resultant 0 over ``tbar_0``; the median makes it robust to an
   earlier cosmic ray) and ``s_i`` the noise of the difference (Poisson part
   overestimated for multi-read resultants, which is conservative), inflated by
   ``1 + pi / (2 n)`` for the median of ``n`` estimates.  A full pixel gains only
   what IPC brings from unsaturated neighbours, at most ``4 alpha`` times its own
   former rate (a neighbour still below FW has a lower rate), whereas an
   unsaturated one keeps its rate after linearisation: half the expected increment
   separates them for any ``alpha < 1/8``.  ``floor`` (default 0.75) admits IPC
   losses up to 25 %; a bright pixel that is not near the full well is never tested.

The **onset** is then refined: the resultant just before the first flattened one is
flagged too when its increment shows a deficit of more than 3 standard deviations
(a resultant that the saturation reached part-way through: its reads after the
onset are clipped, but by less than half an increment), and resultant 0 when
resultant 1 is flattened and resultant 0 is above the floor (a pixel flat from its
first resultant is full from it; the ambiguity, saturation between the first two
reads, leaves one resultant, which cannot give a slope anyway).  Once saturated, all
later resultants of the integration are too.

Estimated last read: a resultant averages its reads, so when only its last reads are
at the full well or the ceiling its mean stays below them while the ramp is already
bent; the level tests use ``e + slope * (t_last - tbar)`` (``slope`` from resultants
0 and 1).

Zero level: the first resultant extrapolated back to the reset,
``R_0 - tbar_0 max(R_1 - R_0, 0) / (tbar_1 - tbar_0)``, but at most the median zero
level of the integration plus ``nsigma`` robust standard deviations (1.4826 MAD) of
the zero levels of its regular pixels.  (The bound assumes that most pixels are not
saturated by resultant 1, and that the bias pattern's spread is small against the
full well: a dark pixel whose bias exceeds the bound by ``floor * p(FW)`` would look
fully saturated.  Reference pixels, whose bias differs, are left out: they collect
no charge and only the ADC ceiling is checked on them.)

Growth: with ``grow``, flags are grown to the ``(2 grow + 1)^2`` box around each
saturated pixel, from the resultant at which it saturates (JWST's
``n_pix_grow_sat``).  With IPC that is not undone, a neighbour receives ``alpha`` of
the saturated pixel's signal, which stops growing at the onset: its ramp bends by
``alpha f`` (7 % of the rate of a 5000 e-/s neighbour of a 2.5e4 e-/s saturated
pixel for ``alpha = 1.5 %``), which biases its slope unless the later resultants are
left out.

Limits: the flattening test needs increments of a few ``nsigma`` read and Poisson
noises near the full well (``f dt >~ 100 e-`` for 5 e- reads); ramps with more than
~1000 resultants to fill the well rely on the level test alone, which misses a
saturated pixel that IPC holds more than ``1 - fraction`` below ``p(FW)``.  A source
that dims by more than half within one resultant while above ``floor`` is flagged
as saturated.  The flags' measured accuracy on the example scenes is in
``docs/VALIDATION_FIT.md``.
"""

from dataclasses import dataclass

import numpy as np

from noise.errors import ParameterError
from noise.validate import check_float, check_int, check_mask, describe

from scenesim.detector.nonlinearity import Nonlinearity

__all__ = ["SaturationOptions", "saturation_flags", "zero_level_bound"]

#: Flattening test: a resultant difference below this fraction of the increment
#: expected from the ramp's earlier rate may be a saturated one.
_FLAT_FRACTION = 0.5
#: Sigma of the onset test (the resultant before the first flattened one).
_ONSET_SIGMA = 3.0
#: Earlier rate estimates whose median is the reference rate of the flattening test.
_RATE_WINDOW = 16


@dataclass(frozen=True)
class SaturationOptions:
    """What :func:`saturation_flags` tests against, validated once.

    Parameters
    ----------
    full_well : float, e-
        Full well (>= 0; 0: only the ADC ceiling is checked).
    adc_ceiling_e : float, e-
        ADC ceiling in electrons (>= 0).
    fraction : float
        Level test: fraction of ``p(full_well)`` above the zero level, in (0, 1].
    read_noise : float, e- per read
        White read noise of one read (not CDS), >= 0, for the flattening test.
    nonlinearity : scenesim.detector.nonlinearity.Nonlinearity or None
        Classical nonlinearity of the signal (header ``NLCOEFF``).
    floor : float
        Flattening test: least level, as a fraction of ``p(full_well)`` above the
        zero level, in (0, ``fraction``].
    nsigma : float
        Flattening test threshold (standard deviations, > 0), and the zero-level
        bound.
    grow : int
        Box half-width (pixels, >= 0) over which flags are grown; 0: none.
    """

    full_well: float
    adc_ceiling_e: float
    fraction: float = 0.97
    read_noise: float = 0.0
    nonlinearity: object = None
    floor: float = 0.75
    nsigma: float = 5.0
    grow: int = 0

    def __post_init__(self):
        for name in ("full_well", "adc_ceiling_e", "read_noise"):
            object.__setattr__(self, name, check_float(name, getattr(self, name),
                                                       minimum=0.0))
        fraction = check_float("fraction", self.fraction, minimum=0.0, maximum=1.0,
                               strict_min=True)
        object.__setattr__(self, "fraction", fraction)
        object.__setattr__(self, "floor", check_float(
            "floor", self.floor, minimum=0.0, maximum=fraction, strict_min=True))
        object.__setattr__(self, "nsigma", check_float("nsigma", self.nsigma,
                                                       minimum=0.0, strict_min=True))
        object.__setattr__(self, "grow", check_int("grow", self.grow, minimum=0))
        if self.nonlinearity is not None and not isinstance(self.nonlinearity,
                                                            Nonlinearity):
            raise ParameterError(
                f"'nonlinearity' must be None or a "
                f"scenesim.detector.nonlinearity.Nonlinearity, got "
                f"{type(self.nonlinearity).__name__}")

    @property
    def full_signal(self):
        """``p(full_well)``: the most any pixel can read above its zero level, e-."""
        fw = self.full_well
        if self.nonlinearity is None:
            return fw
        return float(self.nonlinearity.apply(min(fw, self.nonlinearity.q_hi)))


def saturation_flags(e, tbar, options, *, t_last=None, n_reads=None, refmask=None,
                     zero_bound=None):
    """Boolean flags of saturated resultants, same shape as ``e`` (nints, nres, ny, nx).

    The three tests, the onset and the growth of the module notes.

    Parameters
    ----------
    e : ndarray, shape (nints, nres, ny, nx), float, e-
        Resultants (DN times gain, nothing subtracted).
    tbar : ndarray, shape (nres,), s
        Mean read time of each resultant from reset, increasing.
    options : SaturationOptions
        Full well, ADC ceiling and the tests' settings.
    t_last : ndarray, shape (nres,), s, keyword-only, optional
        Time of the last read of each resultant (default ``tbar``): the level tests
        are made on the estimated last read (module notes).
    n_reads : ndarray, shape (nres,), int, keyword-only, optional
        Reads averaged in each resultant (default 1).
    refmask : ndarray of bool, shape (ny, nx), keyword-only, optional
        Reference pixels: only the ADC ceiling is checked, and their zero levels
        are left out of the bound.
    zero_bound : ndarray, shape (nints,), float32, e-, keyword-only, optional
        The bound of the zero levels (module notes), when ``e`` is a block of rows
        of a larger frame: :func:`zero_level_bound` of the whole frame's first two
        resultants, so that the flags of each block are those of the whole frame
        (the other tests are per pixel; growth needs ``grow`` rows of margin).
        None: computed from ``e``.

    Returns
    -------
    ndarray of bool, shape of ``e``
        Once a resultant is saturated, all later ones of the integration are too.

    Raises
    ------
    noise.errors.ParameterError
        Bad argument (before any work).
    """
    if not isinstance(options, SaturationOptions):
        raise ParameterError(f"'options' must be a SaturationOptions, got "
                             f"{type(options).__name__}")
    tbar, t_last, n_reads, refmask = _check_ramp_args(e, tbar, t_last, n_reads, refmask)
    nres = e.shape[1]
    if nres < 2:
        last, slope = e, None
    else:
        slope = np.maximum(e[:, 1] - e[:, 0], 0) / np.float32(tbar[1] - tbar[0])
        lead = (t_last - tbar).astype(np.float32)
        last = e + slope[:, None] * lead[None, :, None, None]
    sat = last >= options.adc_ceiling_e
    if options.full_well > 0 and nres >= 2:
        _full_well_flags(e, last, slope, sat, tbar, n_reads, refmask, options,
                         zero_bound)
    sat = np.maximum.accumulate(sat, axis=1)          # once saturated, stay saturated
    if options.grow and sat.any():
        sat = _grown(sat, options.grow)
    return sat


def _check_ramp_args(e, tbar, t_last, n_reads, refmask):
    """Validate the per-exposure arrays; return (tbar, t_last, n_reads) float64 and
    the reference mask (bool ndarray or None)."""
    if not isinstance(e, np.ndarray) or e.ndim != 4 or e.dtype.kind != "f":
        raise ParameterError(
            f"'e' must be a float array of shape (nints, nres, ny, nx), got "
            f"{type(e).__name__} {getattr(e, 'shape', '')}")
    nres = e.shape[1]

    def times(name, value):
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            arr = None
        if arr is None or arr.shape != (nres,) or not np.all(np.isfinite(arr)):
            raise ParameterError(
                f"{name!r} must be {nres} finite times (s), one per resultant, got "
                f"{describe(value)}")
        return arr

    tbar = times("tbar", tbar)
    t_last = tbar if t_last is None else times("t_last", t_last)
    if nres >= 2 and np.any(np.diff(tbar) <= 0):
        raise ParameterError(f"'tbar' must increase strictly, got {tbar.tolist()!r}")
    if refmask is not None:
        refmask = check_mask("refmask", refmask, e.shape[2:])
    if n_reads is None:
        return tbar, t_last, np.ones(nres), refmask
    try:
        n_reads = np.asarray(n_reads, dtype=np.float64)
    except (TypeError, ValueError):
        n_reads = np.zeros(0)
    if n_reads.shape != (nres,) or np.any(n_reads < 1) \
            or np.any(n_reads != np.round(n_reads)):
        raise ParameterError(
            f"'n_reads' must be {nres} integers >= 1 (reads per resultant), got "
            f"{describe(n_reads)}")
    return tbar, t_last, n_reads, refmask


def _full_well_flags(e, last, slope, sat, tbar, n_reads, refmask, options, bound):
    """Level and flattening tests (module notes); update ``sat`` in place."""
    m_full = options.full_signal
    zero = e[:, 0] - slope * np.float32(tbar[0])
    if bound is None:
        bound = _bound(zero, refmask, options.nsigma)
    zero = np.minimum(zero, np.asarray(bound, np.float32)[:, None, None])
    above = last - zero[:, None]
    high = above >= np.float32(options.floor * m_full)
    level = above >= np.float32(options.fraction * m_full)
    if refmask is not None:
        regular = ~refmask
        high &= regular
        sat |= level & regular
    else:
        sat |= level
    cand = np.nonzero(high.any(axis=1))               # (int, y, x) of candidates
    if cand[0].size:
        sat[cand[0], :, cand[1], cand[2]] |= _flattened(
            e[cand[0], :, cand[1], cand[2]].astype(np.float64),
            zero[cand].astype(np.float64), high[cand[0], :, cand[1], cand[2]],
            sat[cand[0], :, cand[1], cand[2]], tbar, n_reads,
            float(options.read_noise), options.nonlinearity, float(options.nsigma))


def zero_level_bound(first_two, tbar, *, refmask=None, nsigma=5.0):
    """The bound of the zero levels of :func:`saturation_flags` (module notes).

    Parameters
    ----------
    first_two : ndarray, shape (nints, 2, ny, nx), float, e-
        The first two resultants of each integration, whole frames.
    tbar : ndarray, shape (2,) or more, s
        Mean read times of (at least) those two resultants.
    refmask : ndarray of bool, shape (ny, nx), keyword-only, optional
        Reference pixels, left out.
    nsigma : float, keyword-only
        As :attr:`SaturationOptions.nsigma`.

    Returns
    -------
    ndarray, shape (nints,), float32, e-
        Median zero level plus ``nsigma`` robust standard deviations.
    """
    e = np.asarray(first_two)
    t = np.asarray(tbar, dtype=np.float64)
    slope = np.maximum(e[:, 1] - e[:, 0], 0) / np.float32(t[1] - t[0])
    return _bound(e[:, 0] - slope * np.float32(t[0]), refmask, nsigma)


def _bound(zero, refmask, nsigma):
    """Median plus ``nsigma`` robust standard deviations of the zero levels
    (nints, ny, nx) of the regular pixels: (nints,) float32."""
    nints = zero.shape[0]
    regular = None if refmask is None else ~refmask
    zs = zero.reshape(nints, -1) if regular is None or not regular.any() \
        else zero[:, regular]
    med = np.median(zs, axis=1)
    spread = 1.4826 * np.median(np.abs(zs - med[:, None]), axis=1)
    return (med + nsigma * spread).astype(np.float32)


def _grown(sat, grow):
    """Flags grown to the ``(2 grow + 1)^2`` box from the resultant of saturation."""
    nres, ny, nx = sat.shape[1:]
    first = np.where(sat.any(axis=1), sat.argmax(axis=1), nres)   # (nints, ny, nx)
    grown = first.copy()
    for dy in range(-grow, grow + 1):
        for dx in range(-grow, grow + 1):
            dst = (slice(None), slice(max(dy, 0), ny + min(dy, 0)),
                   slice(max(dx, 0), nx + min(dx, 0)))
            src = (slice(None), slice(max(-dy, 0), ny + min(-dy, 0)),
                   slice(max(-dx, 0), nx + min(-dx, 0)))
            np.minimum(grown[dst], first[src], out=grown[dst])
    return np.arange(nres)[None, :, None, None] >= grown[:, None]


def _flattened(r, zero, high, sat, tbar, n_reads, read_noise, nl, nsigma):
    """Flattening and onset tests of :func:`saturation_flags` on candidate ramps.

    Parameters
    ----------
    r : ndarray, shape (n, nres), float64, e-
        Resultants of ``n`` candidate (integration, pixel) ramps.
    zero : ndarray, shape (n,), float64, e-
        Their zero levels.
    high : ndarray of bool, shape (n, nres)
        Resultants above the floor.
    sat : ndarray of bool, shape (n, nres)
        Resultants already flagged (ADC ceiling, level).
    tbar, n_reads : ndarray, shape (nres,)
    read_noise : float, e- per read
    nl : scenesim.detector.nonlinearity.Nonlinearity or None
    nsigma : float

    Returns
    -------
    ndarray of bool, shape (n, nres)
        Flattened resultants, their onset, and the earlier flags (not yet sticky).
    """
    n, nres = r.shape
    q = r - zero[:, None]
    if nl is not None:
        lo, hi = nl.measured_range
        q = nl.invert(np.clip(q, np.nextafter(lo, np.inf), np.nextafter(hi, -np.inf)))
    flat, onset = _deficits(q, tbar, n_reads, read_noise, nsigma, high)
    first = np.where(flat.any(axis=1), flat.argmax(axis=1), nres)
    # one step back from the first flattened resultant when the one before shows the
    # onset (saturation part-way through a resultant bends only that resultant, so
    # one step suffices; going on would follow the few-% slope changes that IPC
    # makes when a neighbour saturates).  Not from a level flag: that one is early
    # by design.
    prev = first - 1
    ok = (prev >= 0) & (first < nres)
    ok[ok] = onset[np.arange(n)[ok], prev[ok]]
    first = np.where(ok, prev, first)
    first = np.minimum(first, np.where(sat.any(axis=1), sat.argmax(axis=1), nres))
    return np.arange(nres)[None, :] >= first[:, None]


def _deficits(q, tbar, n_reads, read_noise, nsigma, high):
    """Flattened resultants and onsets (n, nres) bool of linearised ramps ``q``."""
    n, nres = q.shape
    dt = np.diff(tbar)
    # rate estimates: charge of resultant 0 over tbar_0 (when tbar_0 > 0), then the
    # differences; NaN where there is none
    rates = np.full((n, nres), np.nan)
    if tbar[0] > 0:
        rates[:, 0] = q[:, 0] / tbar[0]
    rates[:, 1:] = np.diff(q, axis=1) / dt
    flat = np.zeros((n, nres), dtype=bool)
    onset = np.zeros((n, nres), dtype=bool)
    for i in range(1, nres):
        window = rates[:, max(0, i - _RATE_WINDOW):i]
        known = np.isfinite(window).sum(axis=1)
        if not known.any():
            continue
        with np.errstate(all="ignore"):
            f = np.nanmedian(window, axis=1) if np.isnan(window).any() \
                else np.median(window, axis=1)
        f = np.where(known > 0, f, 0.0)
        expected = np.maximum(f, 0.0) * dt[i - 1]
        var = (read_noise ** 2 * (1 / n_reads[i - 1] + 1 / n_reads[i]) + expected)
        var *= 1 + np.pi / (2 * np.maximum(known, 1))
        deficit = expected - (q[:, i] - q[:, i - 1])
        test = high[:, i] & (known > 0)
        flat[:, i] = test & (deficit > np.maximum(nsigma * np.sqrt(var),
                                                  _FLAT_FRACTION * expected))
        onset[:, i] = test & (deficit > _ONSET_SIGMA * np.sqrt(var))
    onset[:, 0] = high[:, 0] & flat[:, 1]
    return flat, onset
