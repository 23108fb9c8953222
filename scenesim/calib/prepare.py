"""Fit an exposure: DN to electrons, reference correction, saturation, slopes.

:func:`prepare_exposure` is the one pre-processing of an exposure before any fitter:
it takes an exposure file (JWST uncal layout, see :mod:`scenesim.io.exposure`) or the
same contents in memory (:class:`scenesim.io.exposure.Exposure`, e.g. from a run that
writes no ramp file), converts DN to electrons with the header's ``GAIN``, undoes
the IPC recorded in the header (see "IPC is undone" below), flags saturated
resultants, corrects the reference pixels (:mod:`scenesim.calib.refpix`), inverts the
classical nonlinearity recorded in the header,
removes the per-output common mode that the reference pixels missed and measures
the effective read noise per column, and returns the result as a
:class:`PreparedExposure`.  :func:`fit_exposure_file` fits its slopes
(:mod:`scenesim.rampfit.fit`) and writes the slope file;
:func:`scenesim.adapters.stcal.fit_exposure_stcal` hands the very same arrays to
stcal, so that comparing the two isolates the fitter.

Noise model from the data (see :mod:`scenesim.rampfit.fit`, "Read noise from the data"): the
header's ``RDNOISE`` is the white noise of one read, but after the reference
correction the ramps also carry (i) noise common to all pixels of an output, read by
read, and (ii) residual row banding.  (i) is a slow wander of every ramp of the
output, which the GLS jump test (a step test) flags as jumps; it is estimated from
the regular pixels (median over each output of the residuals from each pixel's
line, :func:`scenesim.rampfit.fit.common_mode`, on at most 64 rows) and subtracted, except
its mean rate, which cannot be told from a uniform background.  (ii) is white in
each pixel's ramp and depends on the column (the time within the row at which the
pixel is read): the read noise is rescaled per column so that the median ``chi2``
of read-noise dominated pixels is that of a right model
(:func:`scenesim.rampfit.fit.measure_read_noise`, on at most 256 rows).  The file records
the model value (``RNMODEL``), the median fitted value (``RNOISE``) and whether the
corrections ran (``RNSOURCE``, ``CMREMOVE``).  On the cosmic-ray scene (H2RG stripe,
60 RAPID groups, ``nirspec`` noise) they lower the false-positive jump rate from
3.9 % to 0.03 % of clean pixels and the mean ``chi2`` from 1.54 to 1.00, keep all
1129 in-ramp hits above 10 sigma, and cost ~2 s on top of a ~3 s fit (the 256-row
stripe is fitted twice more, without jump detection, to measure the noise; a full
2048-row frame uses 1/8 of its rows).

Caveat (measured): the common mode is estimated from a finite number of pixels and
its removal moves all slopes of an output together by the estimate's error.  On
128 x 128 white-noise exposures at rate 0 (``refpix='none'``) the mean slope of an
output moved by up to 0.07 sigma of one pixel's slope for RAPID x 10, and by up to
0.5 sigma for the uneven 9-resultant Roman-like table: :func:`scenesim.rampfit.fit.common_mode`
keeps the *unweighted* mean of its per-difference offsets, whereas a fit is moved
by their fit-weighted mean (for that table dominated by the short first
differences).  Keeping the GLS-weighted mean instead (weights at rate 0) brought the
shifts below 0.001 sigma in the same test.  Analyses that need independent pixels
should pass ``remove_common_mode=False``.

Order of the steps: saturation is judged on the raw ramps in e- (before the
reference correction, as the JWST pipeline's saturation step precedes its
reference-pixel step); the common mode is estimated on the corrected ramps, and the
read noise on the ramps without it.

Conventions: read noise is **per read** in e- (header ``RDNOISE``, the white
component; not CDS).

Saturation is judged from the ramp alone, as a pipeline would without a reference
file (:func:`saturation_flags`).  A pixel held at the full well does not read
``FULLWELL`` above its zero level: the classical nonlinearity recorded in the header
(``NLCOEFF``) lowers it to ``p(FW)`` and IPC moves ``4 alpha`` of it into neighbours
that hold less.  On the bright-star scene (``p(FW) = 0.923 FW``, ``alpha = 1.5 %``)
the saturated core pixels read 0.90-0.92 FW, so the former rule "the estimated last
read is 97 % of ``FULLWELL`` above the zero level" flagged none of the 5 pixels that
reach the full well (the jump test cut their flat ramps instead, two of them to
~450 e-/s for 3.5e4 and 2.8e4 e-/s), and it never flagged a pixel saturated before
its second resultant (its flat first difference puts its zero level on its
plateau).  A resultant is now saturated when (1) its estimated last read is at the
ADC ceiling, or (2) at 97 % of ``p(FW)`` above the zero level (``p(FW)`` bounds what
any pixel can read, IPC included), or (3) it is above 75 % of ``p(FW)`` and the
linearised ramp flattens there: its increment falls short of the one the ramp's
earlier rate predicts by more than half of it and more than 5 sigma (a full pixel
gains only what IPC brings, ``<= 4 alpha`` of its former rate); the resultant just
before a flattened one is flagged too when its own increment falls short by more
than 3 sigma (saturation part-way through it).  The zero level is bounded by the
image's median zero level plus 5 robust sigma.  Measured on the bright-star scene (8
seeds, 40 saturating pixel ramps, before IPC was undone): all flagged at the
resultant where the charge reaches the full well (one a resultant early), none of
the pixels that stay below the full well flagged by the tests themselves (the
brightest of them reaches 0.916 FW); mean ``(fit - truth)/sigma`` in the 1e3-1e4
e-/s bin -1.37 -> -0.27 +- 0.08 (``chi2`` 6.5 -> 0.93), above 1e4 e-/s -618 ->
-0.30 +- 0.13 (``chi2`` 1.3e6 -> 1.14); the same on 40-star fields, 8-read
resultants with 2 integrations and the uneven Roman-like table (every saturating
ramp flagged within one resultant).  Cost: 1.2 s for 2048 x 2048 x 10 resultants
(the flattening test runs only on pixels above the floor).

IPC is undone before the flags and the linearisation
----------------------------------------------------
The engine reads ``F K(p(q))`` (flat ``F``, IPC kernel ``K``, nonlinearity ``p``,
charge ``q``).  Inverting ``p`` pixel by pixel on that signal (as before) mixes
``p`` of neighbours that hold different charges: with nonlinearity *and* IPC
together (either alone gave <= 0.03 sigma) the bright-star bins above 1e3 e-/s kept
a -0.3 sigma bias, also without noise, the neighbours of bright pixels down to -0.8
sigma.  ``K`` is linear, so ``K^-1`` of a resultant is exactly the mean over its
reads of ``p(q)``; :func:`linearize_resultants` then inverts ``p`` as before (its
documented error for multi-read resultants, ``~ c2 var(q within the group)``, is
unchanged).  When the header records the kernel (``IPCKERN``, written by
:mod:`scenesim.io.exposure`), :func:`prepare_exposure` therefore undoes it on every
resultant of the whole frame right after DN -> e- (:func:`undo_ipc`, the exact
inverse of :func:`scenesim.detector.ipc.apply_ipc`, edges included: the engine applies
IPC to the reference pixels too, so they get back to their own signal), before the
saturation flags, the reference correction and the linearisation; the fit
reports then each pixel's *own* rate (truth ``RATE`` without a flat; ``K^-1`` of
``RATE_IPC`` in general), not ``RATE_IPC``.  Consequences:

* saturation: a full pixel reads exactly ``p(FW)`` above its zero level, and its
  neighbours no longer bend when it stops collecting, so flags are **not** grown to
  the 3 x 3 neighbours (``grow = 1``, as JWST's ``n_pix_grow_sat``, stays for IPC
  that is not undone: ``deconvolve_ipc=False``, or a file without ``IPCKERN``).  The
  ADC clip is not linear (``K^-1`` would spread a clipped pixel's error, ``alpha``
  of the clipped signal, into its neighbours): it is tested on the raw ramps and its
  flags are grown to the 3 x 3 box;
* noise: white read noise, added after IPC, comes out amplified by ``g = sqrt(sum
  (K^-1)^2)`` (:func:`ipc_noise_gain`: 1.065 for ``alpha = 1.5 %``) and slightly
  anticorrelated between neighbours; the model read noise is multiplied by ``g``
  (``RNMODEL``; ``IPCRNFAC`` records ``g``) and the measured one follows the data.
  Shot noise, drawn before IPC, comes back white, with the variance of the pixel's
  own rate, which is what the fitter assumes (before, the reported ``chi2`` of
  bright pixels was 0.87-0.92, IPC having smoothed their shot noise);
* flat field: the engine applies it after IPC, and the fitter does not know it:
  ``K^-1(F K m) = F m + [K^-1, F] K m``, an error ~ ``alpha (F_p - F_n) m_n`` (3e-4
  of a neighbour's signal for a 2 % flat rms) in the linearised signal, and the fit
  recovers ``K^-1 RATE_IPC`` (exactly, for linear ramps), not ``F RATE``.

Measured on the bright-star scene (seeds 100-139, GLS, ``(fit - truth)/sigma``
pooled, truth ``RATE_IPC`` before and ``K^-1 RATE_IPC`` after): 1e2-1e3 e-/s
-0.077 +- 0.028 -> -0.023 +- 0.029, 1e3-1e4 e-/s -0.231 +- 0.035 -> +0.007 +-
0.038, above 1e4 e-/s -0.360 +- 0.057 -> -0.044 +- 0.063; the unsaturated
neighbours of saturating pixels -0.27 +- 0.04 -> +0.02 +- 0.05; mean fitted
``chi2`` 0.91/0.89/0.94 -> 1.00/1.00/1.05; pixels with a DQ flag 768 -> 208 (no
growth).  Without noise (4 seeds) the three bins went from -0.06/-0.24/-0.31 to
+0.006/+0.006/-0.002 sigma.  The 200 saturating ramps were flagged at the resultant
where the charge reaches the full well (79) or one resultant early (121, the 97 %
level test), none late or missed, and no pixel that stays below the full well was
flagged (560 with the growth).  Cost on 2048 x 2048 x 20 resultants: 6
iterations, 1.16 s on one thread and 0.72 s on two, out of a 16 s fit.
"""

import math
import numbers
import os
from dataclasses import dataclass

import numpy as np
from astropy.io import fits

from noise.clock import Detector, detector_from_header
from noise.errors import ParameterError

from scenesim.detector.ipc import ipc_noise_gain, undo_ipc
from scenesim.detector.nonlinearity import linearize_resultants
from scenesim.detector.readout import Readout
from scenesim.io.exposure import Exposure
from scenesim.io.header import (COPIED_KEYS, card, exposure_card, exposure_read_noise,
                                exposure_readout, header_ipc_kernel,
                                header_nonlinearity)
from scenesim.calib.noise_model import common_mode, measure_read_noise
from scenesim.io.fitfile import write_fit
from scenesim.rampfit.fitter import FITTERS, fit_ramps

__all__ = ["PreparedExposure", "prepare_exposure", "load_exposure", "fit_exposure_file",
           "saturation_flags", "REFPIX_SCHEMES"]

REFPIX_SCHEMES = ("none", "median", "jwst")


@dataclass(frozen=True, eq=False)
class PreparedExposure:
    """An exposure made ready for a ramp fitter by :func:`prepare_exposure`.

    Parameters
    ----------
    name : str
        The exposure's path, or ``Exposure.name`` for one in memory.
    header : astropy.io.fits.Header
        The exposure's primary header.
    detector : noise.clock.Detector
        From the header.
    readout : scenesim.detector.readout.Readout
        From the ``READS`` table and the header.
    gain : float
        e-/DN (header ``GAIN``).
    t_frame : float
        Frame time, s (header ``TFRAME``).
    electrons : ndarray, shape (nints, ngroups, ny, nx), float32, e-
        Resultants in electrons after IPC undone, the reference correction, the
        linearisation and the common-mode removal (whichever were asked for and
        apply).
    saturated : ndarray of bool, shape of ``electrons``
        Saturated resultants (:func:`saturation_flags`; sticky within an
        integration).
    read_times : list of ngroups ndarrays, s from each pixel's reset
        Read times of every resultant: ``(N_i,)`` for a rolling reset, ``(N_i, ny,
        nx)`` for a global reset (see :meth:`scenesim.detector.readout.Readout.read_times`).
    read_noise : float or ndarray (ny, nx) float64, e- per read
        White read noise of one read (not CDS) the fitter should use: the measured
        per-column map when ``measure_noise``, else ``read_noise_model``.
    read_noise_model : float
        Model white read noise, e- per read (header ``RDNOISE`` or the caller's,
        times :func:`ipc_noise_gain` when IPC was undone).
    refmask : ndarray of bool, shape (ny, nx)
        Reference pixels.
    cards : tuple of (str, value, str)
        FITS cards recording the exposure and what was done to it (``EXPOSURE``,
        ``REFPIX``, ``RNCONV``, ``RNMODEL``, ``RNSOURCE``, ``CMREMOVE``,
        ``IPCDECON``: IPC undone, ``IPCRNFAC``: the read-noise factor that came with
        it (1 if not), ``LINCORR``) and the exposure keywords copied from its header
        (``DETECTOR``, ``READPATT``, ``SEED``, ``IPC``, ``IPCKERN``, ...); every card
        fits in 80 characters (a long ``IPCKERN`` string becomes CONTINUE cards).
    """

    name: str
    header: fits.Header
    detector: Detector
    readout: Readout
    gain: float
    t_frame: float
    electrons: np.ndarray
    saturated: np.ndarray
    read_times: list
    read_noise: object
    read_noise_model: float
    refmask: np.ndarray
    cards: tuple


#: Truncation error of the IPC deconvolution in :func:`prepare_exposure`, as a
#: fraction of the noise of one read (white read noise and ADC quantisation).
_IPC_TOLERANCE = 1e-3

#: Flattening test: a resultant difference below this fraction of the increment
#: expected from the ramp's earlier rate may be a saturated one (see
#: :func:`saturation_flags`).
_FLAT_FRACTION = 0.5
#: Sigma of the onset test (the resultant before the first flattened one).
_ONSET_SIGMA = 3.0
#: Earlier rate estimates whose median is the reference rate of the flattening test.
_RATE_WINDOW = 16


def _check_saturation_args(e, tbar, full_well, adc_ceiling_e, fraction, t_last,
                           n_reads, read_noise, nonlinearity, floor, nsigma, grow,
                           refmask):
    """Validate :func:`saturation_flags`' arguments; return (tbar, t_last, n_reads)."""
    from scenesim.detector.nonlinearity import Nonlinearity
    if not isinstance(e, np.ndarray) or e.ndim != 4 or e.dtype.kind != "f":
        raise ParameterError(
            f"'e' must be a float array of shape (nints, nres, ny, nx), got "
            f"{type(e).__name__} {getattr(e, 'shape', '')}")
    nres = e.shape[1]

    def times(name, value):
        arr = np.asarray(value, dtype=np.float64)
        if arr.shape != (nres,) or not np.all(np.isfinite(arr)):
            raise ParameterError(
                f"{name!r} must be {nres} finite times (s), one per resultant, got "
                f"{value!r}")
        return arr

    tbar = times("tbar", tbar)
    t_last = tbar if t_last is None else times("t_last", t_last)
    if nres >= 2 and np.any(np.diff(tbar) <= 0):
        raise ParameterError(f"'tbar' must increase strictly, got {tbar.tolist()!r}")
    for name, value in (("full_well", full_well), ("adc_ceiling_e", adc_ceiling_e),
                        ("read_noise", read_noise)):
        if (isinstance(value, bool) or not isinstance(value, numbers.Real)
                or not math.isfinite(value) or value < 0):
            raise ParameterError(
                f"{name!r} must be a finite number >= 0 (e-), got {value!r}")
    if isinstance(fraction, bool) or not isinstance(fraction, numbers.Real) \
            or not 0 < fraction <= 1:
        raise ParameterError(f"'fraction' must be in (0, 1], got {fraction!r}")
    if isinstance(floor, bool) or not isinstance(floor, numbers.Real) \
            or not 0 < floor <= fraction:
        raise ParameterError(
            f"'floor' must be in (0, fraction={fraction!r}], got {floor!r}")
    if isinstance(nsigma, bool) or not isinstance(nsigma, numbers.Real) \
            or not math.isfinite(nsigma) or nsigma <= 0:
        raise ParameterError(f"'nsigma' must be a finite number > 0, got {nsigma!r}")
    if isinstance(grow, bool) or not isinstance(grow, numbers.Integral) or grow < 0:
        raise ParameterError(f"'grow' must be an integer >= 0 (pixels), got {grow!r}")
    if refmask is not None and (not isinstance(refmask, np.ndarray)
                                or refmask.dtype != bool
                                or refmask.shape != e.shape[2:]):
        raise ParameterError(
            f"'refmask' must be None or a bool array of shape {e.shape[2:]}, got "
            f"{type(refmask).__name__} {getattr(refmask, 'shape', '')}")
    if nonlinearity is not None and not isinstance(nonlinearity, Nonlinearity):
        raise ParameterError(
            f"'nonlinearity' must be None or a scenesim.detector.nonlinearity.Nonlinearity, got "
            f"{type(nonlinearity).__name__}")
    if n_reads is None:
        n_reads = np.ones(nres)
    else:
        n_reads = np.asarray(n_reads, dtype=np.float64)
        if n_reads.shape != (nres,) or np.any(n_reads < 1) \
                or np.any(n_reads != np.round(n_reads)):
            raise ParameterError(
                f"'n_reads' must be {nres} integers >= 1 (reads per resultant), got "
                f"{n_reads!r}")
    return tbar, t_last, n_reads


def saturation_flags(e, tbar, full_well, adc_ceiling_e, *, fraction=0.97, t_last=None,
                     n_reads=None, read_noise=0.0, nonlinearity=None, floor=0.75,
                     nsigma=5.0, grow=0, refmask=None):
    """Boolean flags of saturated resultants, same shape as ``e`` (nints, nres, ny, nx).

    A pixel at full well does not read ``full_well`` above its zero level: the
    classical nonlinearity lowers it to ``p(FW)`` (7.7 % lower for the bright-star
    scene's ``c2 = -8e-7, c3 = -2e-12`` at 8e4 e-), and IPC moves ``4 alpha + 4
    alpha_diag`` of it into neighbours that hold less (6 % for ``alpha = 1.5 %``), so
    a level test alone either misses saturated pixels or, with a threshold low
    enough for every IPC kernel, flags bright unsaturated ones.  Three tests are
    therefore combined; a resultant is saturated when any of them says so:

    1. **ADC ceiling**: the estimated last read (below) is at the ceiling.
    2. **Level**: the estimated last read is at least ``fraction * p(FW)`` above
       the zero level, ``p`` the ``nonlinearity`` (identity when ``None``):
       ``p(FW)`` is the most any pixel can read, IPC included (IPC averages
       neighbours that all hold at most FW), so ``fraction`` keeps its meaning of
       "within 3 % of full".
    3. **Flattening**: the estimated last read is at least ``floor * p(FW)`` above
       the zero level, and the increment ``D_i`` of the linearised ramp (``p``
       inverted) over the previous resultant falls below the increment expected
       from the ramp's earlier rate, ``f_i dt_i``, by more than both ``nsigma``
       standard deviations and half of it::

           f_i dt_i - D_i > max(nsigma * s_i, f_i dt_i / 2),
           s_i^2 = read_noise^2 (1/N_{i-1} + 1/N_i) + max(f_i, 0) dt_i,

       with ``f_i`` the median of the (up to 16) previous rate estimates (the
       first one is the charge of resultant 0 over ``tbar_0``; the median makes it
       robust to an earlier cosmic ray) and ``s_i`` the noise of the difference
       (Poisson part overestimated for multi-read resultants, which is
       conservative), inflated by ``1 + pi / (2 n)`` for the median of ``n``
       estimates.  A full pixel gains only what IPC brings from unsaturated
       neighbours, at most ``4 alpha`` times its own former rate (a neighbour still
       below FW has a lower rate), whereas an unsaturated one keeps its rate after
       linearisation: half the expected increment separates them for any
       ``alpha < 1/8``.  ``floor`` (default 0.75) admits IPC losses up to 25 %; a
       bright pixel that is not near the full well is never tested.

    The **onset** is then refined: the resultant just before the first flattened
    one is flagged too when its increment shows a deficit of more than 3 standard
    deviations (a resultant that the saturation reached part-way through: its
    reads after the onset are clipped, but by less than half an increment), and
    resultant 0 when resultant 1 is flattened and resultant 0 is above the floor (a
    pixel flat from its first resultant is full from it; the ambiguity, saturation
    between the first two reads, leaves one resultant, which cannot give a slope
    anyway).
    Once saturated, all later resultants of the integration are too.

    Zero level: the first resultant extrapolated back to the reset,
    ``R_0 - tbar_0 max(R_1 - R_0, 0) / (tbar_1 - tbar_0)``, but at most the median
    zero level of the integration plus ``nsigma`` robust standard deviations
    (1.4826 MAD) of the zero levels of its regular pixels: a pixel that saturates
    before resultant 1 has a flat first difference, which would put its zero
    level at its plateau.  (The bound assumes that most pixels are not saturated
    by resultant 1, and that the bias pattern's spread is small against the full
    well: a dark pixel whose bias exceeds the bound by ``floor * p(FW)`` would
    look fully saturated.  Reference pixels, whose bias differs, are left out:
    they collect no charge and only the ADC ceiling is checked on them.)

    ``grow``: flags are grown to the ``(2 grow + 1)^2`` box around each saturated
    pixel, from the resultant at which it saturates (JWST's ``n_pix_grow_sat``).
    With IPC, a neighbour receives ``alpha`` of the saturated pixel's signal, which
    stops growing at the onset: its ramp bends by ``alpha f`` (7 % of the rate of a
    5000 e-/s neighbour of a 2.5e4 e-/s saturated pixel for ``alpha = 1.5 %``),
    which biases its slope unless the later resultants are left out.  Without a
    recorded IPC kernel the bend cannot be corrected.

    Parameters
    ----------
    e : ndarray, shape (nints, nres, ny, nx), float, e-
        Resultants (DN times gain, nothing subtracted).
    tbar : ndarray, shape (nres,), s
        Mean read time of each resultant from reset, increasing.
    full_well : float, e-
        Full well (0: only the ADC ceiling is checked).
    adc_ceiling_e : float, e-
        ADC ceiling in electrons.
    fraction : float, keyword-only
        Level test: fraction of ``p(full_well)`` above the zero level, in (0, 1].
    t_last : ndarray, shape (nres,), s, optional
        Time of the last read of each resultant (default ``tbar``).  A resultant
        averages its reads, so when only its last reads are at the full well or the
        ceiling its mean stays below them while the ramp is already bent; the level
        tests are therefore made on the estimated last read,
        ``e + slope * (t_last - tbar)`` (``slope`` from resultants 0 and 1).
    n_reads : ndarray, shape (nres,), int, optional
        Reads averaged in each resultant (default 1).
    read_noise : float, e- per read
        White read noise of one read (not CDS), for the flattening test's noise.
    nonlinearity : scenesim.detector.nonlinearity.Nonlinearity or None
        Classical nonlinearity of the signal (header ``NLCOEFF``).
    floor : float
        Flattening test: least level, as a fraction of ``p(full_well)`` above the
        zero level, in (0, ``fraction``].
    nsigma : float
        Flattening test threshold (standard deviations), and the zero-level bound.
    grow : int
        Box half-width (pixels) over which flags are grown; 0: none.
    refmask : ndarray of bool, shape (ny, nx), optional
        Reference pixels: only the ADC ceiling is checked, and their zero levels
        are left out of the bound.

    Returns
    -------
    ndarray of bool, shape of ``e``
        Once a resultant is saturated, all later ones of the integration are too.

    Raises
    ------
    noise.errors.ParameterError
        Bad argument (before any work).

    Notes
    -----
    Limits: the flattening test needs increments of a few ``nsigma`` read and
    Poisson noises near the full well (``f dt >~ 100 e-`` for 5 e- reads); ramps
    with more than ~1000 resultants to fill the well rely on the level test alone,
    which misses a saturated pixel that IPC holds more than ``1 - fraction`` below
    ``p(FW)``.  A source that dims by more than half within one resultant while
    above ``floor`` is flagged as saturated.
    """
    tbar, t_last, n_reads = _check_saturation_args(
        e, tbar, full_well, adc_ceiling_e, fraction, t_last, n_reads, read_noise,
        nonlinearity, floor, nsigma, grow, refmask)
    nints, nres, ny, nx = e.shape
    if nres < 2:
        last = e
        slope = None
    else:
        slope = np.maximum(e[:, 1] - e[:, 0], 0) / np.float32(tbar[1] - tbar[0])
        lead = (t_last - tbar).astype(np.float32)
        last = e + slope[:, None] * lead[None, :, None, None]
    sat = last >= adc_ceiling_e
    if full_well > 0 and nres >= 2:
        fw = float(full_well)
        if nonlinearity is not None:
            fw = min(fw, nonlinearity.q_hi)
            m_full = float(nonlinearity.apply(fw))
        else:
            m_full = fw
        zero = e[:, 0] - slope * np.float32(tbar[0])
        regular = None if refmask is None else ~refmask
        zs = zero.reshape(nints, -1) if regular is None or not regular.any() \
            else zero[:, regular]
        med = np.median(zs, axis=1)
        spread = 1.4826 * np.median(np.abs(zs - med[:, None]), axis=1)
        bound = (med + nsigma * spread).astype(np.float32)
        zero = np.minimum(zero, bound[:, None, None])
        above = last - zero[:, None]
        high = above >= np.float32(floor * m_full)
        if regular is not None:
            high &= regular
            sat |= (above >= np.float32(fraction * m_full)) & regular
        else:
            sat |= above >= np.float32(fraction * m_full)
        cand = np.nonzero(high.any(axis=1))               # (int, y, x) of candidates
        if cand[0].size:
            sat[cand[0], :, cand[1], cand[2]] |= _flattened(
                e[cand[0], :, cand[1], cand[2]].astype(np.float64),
                zero[cand].astype(np.float64), high[cand[0], :, cand[1], cand[2]],
                sat[cand[0], :, cand[1], cand[2]], tbar, n_reads, float(read_noise),
                nonlinearity, float(nsigma))
    # once saturated, stay saturated
    sat = np.maximum.accumulate(sat, axis=1)
    if grow and sat.any():
        first = np.where(sat.any(axis=1), sat.argmax(axis=1), nres)   # (nints, ny, nx)
        grown = first.copy()
        for dy in range(-grow, grow + 1):
            for dx in range(-grow, grow + 1):
                dst = (slice(None), slice(max(dy, 0), ny + min(dy, 0)),
                       slice(max(dx, 0), nx + min(dx, 0)))
                src = (slice(None), slice(max(-dy, 0), ny + min(-dy, 0)),
                       slice(max(-dx, 0), nx + min(-dx, 0)))
                np.minimum(grown[dst], first[src], out=grown[dst])
        sat = np.arange(nres)[None, :, None, None] >= grown[:, None]
    return sat


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


def load_exposure(exposure):
    """An exposure as an :class:`scenesim.io.exposure.Exposure`.

    Parameters
    ----------
    exposure : str, os.PathLike or scenesim.io.exposure.Exposure
        Exposure file (read, ``SCI`` uint16 DN + ``READS`` table), or an exposure
        already in memory (returned as it is).

    Returns
    -------
    scenesim.io.exposure.Exposure

    Raises
    ------
    noise.errors.ParameterError
        ``exposure`` is neither a path nor an ``Exposure``.
    noise.errors.FileFormatError
        Missing file, or no ``SCI`` or ``READS`` extension.
    """
    if isinstance(exposure, Exposure):
        return exposure
    if not isinstance(exposure, (str, os.PathLike)):
        raise ParameterError(
            f"'exposure' must be a path (str or os.PathLike) or a "
            f"scenesim.io.exposure.Exposure, got {type(exposure).__name__}")
    return Exposure.read(exposure)


def _check_prepare_args(refpix, read_noise, remove_common_mode, measure_noise, threads,
                        deconvolve_ipc=True):
    if refpix not in REFPIX_SCHEMES:
        raise ParameterError(
            f"'refpix' must be one of {list(REFPIX_SCHEMES)}, got {refpix!r}")
    for name, flag in (("remove_common_mode", remove_common_mode),
                       ("measure_noise", measure_noise),
                       ("deconvolve_ipc", deconvolve_ipc)):
        if not isinstance(flag, bool):
            raise ParameterError(f"{name!r} must be True or False, got {flag!r}")
    if read_noise is not None and (
            isinstance(read_noise, bool) or not isinstance(read_noise, numbers.Real)
            or not math.isfinite(read_noise) or read_noise < 0):
        raise ParameterError(
            f"'read_noise' must be None (header RDNOISE) or a finite number >= 0 "
            f"(e- per read, not CDS), got {read_noise!r}")
    if threads is not None and (isinstance(threads, bool)
                                or not isinstance(threads, numbers.Integral)
                                or threads < 1):
        raise ParameterError(
            f"'threads' must be an integer >= 1 or None, got {threads!r}")


def prepare_exposure(exposure, *, refpix="jwst", read_noise=None,
                     remove_common_mode=True, measure_noise=True, threads=None,
                     linearize=True, deconvolve_ipc=True):
    """Read an exposure and make its ramps ready for a fitter (see module notes).

    Steps: DN to e- (``GAIN``); IPC undone on every resultant when the header
    records its kernel (``IPCKERN``; :func:`undo_ipc` to 1e-3 of the noise of one
    read, ``sqrt(RDNOISE^2 + GAIN^2 / 12)``; the model read noise is then multiplied
    by :func:`ipc_noise_gain`; see the module notes); saturation flags
    (:func:`saturation_flags` with the header's ``FULLWELL``, ``NLCOEFF``,
    ``RDNOISE`` and ADC ceiling, grown to the 3 x 3 neighbours when the header says
    ``IPC`` and IPC was not undone; with IPC undone, the ADC ceiling is tested on
    the raw ramps and only its flags are grown); reference-pixel correction
    (:func:`scenesim.calib.refpix.correct_reference`); inversion of the classical
    nonlinearity recorded in the header (``NLCOEFF``, :func:`linearize_resultants`);
    removal of the per-output common
    mode (:func:`scenesim.rampfit.fit.common_mode`); per-column read noise measured from the
    ramps (:func:`scenesim.rampfit.fit.measure_read_noise`).

    Parameters
    ----------
    exposure : str, os.PathLike or scenesim.io.exposure.Exposure
        Exposure file written by scenesim (``SCI`` uint16 DN (nints, ngroups, ny,
        nx) + ``READS`` table), or the same contents in memory.
    refpix : {'none', 'median', 'jwst'}, keyword-only
        Reference-pixel correction.
    read_noise : float or None, keyword-only
        Model white read noise, e- per read (not CDS), >= 0; default the header's
        ``RDNOISE``.
    remove_common_mode : bool, keyword-only
        Subtract, per output and read, the noise common to the output's pixels that
        the reference correction left.
    measure_noise : bool, keyword-only
        Rescale the read noise per column to the scatter measured in the ramps;
        False: ``read_noise`` (or ``RDNOISE``) as it is.
    threads : int or None, keyword-only
        Worker threads of the common-mode and read-noise fits (see
        :func:`scenesim.rampfit.fit.fit_ramps`).
    linearize : bool, keyword-only
        Invert the nonlinearity recorded in the header (no-op when there is none).
    deconvolve_ipc : bool, keyword-only
        Undo the IPC kernel recorded in the header (``IPCKERN``; no-op when there is
        none): the slopes are then each pixel's own rate (``K^-1`` of the truth's
        ``RATE_IPC``).  False: the ramps keep IPC, the slopes estimate
        ``RATE_IPC``, and the saturation flags are grown to the 3 x 3 neighbours.

    Returns
    -------
    PreparedExposure

    Raises
    ------
    noise.errors.ParameterError
        Bad parameter (before the exposure is read), or a recorded kernel that
        keeps half of the charge or less in its centre (it cannot be undone by
        this iteration) with ``deconvolve_ipc`` true.
    noise.errors.FileFormatError
        Missing or malformed exposure.
    """
    _check_prepare_args(refpix, read_noise, remove_common_mode, measure_noise, threads,
                        deconvolve_ipc)
    exp = load_exposure(exposure)
    ro = exposure_readout(exp)
    hdr = exp.header
    det = detector_from_header(hdr)
    gain = float(hdr["GAIN"])
    t_frame = float(hdr["TFRAME"])
    rdn = exposure_read_noise(hdr) if read_noise is None else float(read_noise)

    e = exp.sci.astype(np.float32) * np.float32(gain)
    bits = int(hdr.get("ADCBITS", 16))
    ceiling = (2 ** bits - 1) * gain
    tbar = ro.mean_times(t_frame)
    t_last = np.array([t[-1] for t in ro.read_times(t_frame)])
    n_reads = np.asarray(ro.n_per_resultant)
    kernel = header_ipc_kernel(hdr)          # None: no IPC, identity or not recorded
    decon = deconvolve_ipc and kernel is not None
    rn_gain = 1.0
    ceiling_flags = None
    if decon:
        # the ADC clip is not linear: judged on the raw ramps, and grown to the 3 x 3
        # box (undoing IPC spreads a clipped pixel's error into its neighbours)
        if np.any(t_last > tbar) or float(e.max()) >= ceiling:
            ceiling_flags = saturation_flags(e, tbar, 0.0, ceiling, t_last=t_last,
                                             n_reads=n_reads, grow=1)
        tolerance = _IPC_TOLERANCE * math.hypot(rdn, gain / math.sqrt(12))
        try:
            undo_ipc(e, kernel, tolerance=tolerance, out=e,
                     threads=min(os.cpu_count() or 1, 8) if threads is None else threads)
        except ParameterError as exc:
            raise ParameterError(
                f"exposure {exp.name!r}: its IPC kernel (IPCKERN) cannot be "
                f"deconvolved ({exc}); pass deconvolve_ipc=False") from exc
        rn_gain = ipc_noise_gain(kernel)
    rdn_model = rdn * rn_gain
    # growth hides the bend that a saturating pixel puts in its neighbours through
    # IPC; not needed once IPC is undone
    unknown = bool(hdr.get("IPC", False)) and "IPCKERN" not in hdr
    grow = 1 if not decon and (kernel is not None or unknown) else 0
    refmask = det.reference_mask()
    sat = saturation_flags(e, tbar, float(hdr.get("FULLWELL", 0.0)), ceiling,
                           t_last=t_last, n_reads=n_reads, read_noise=rdn_model,
                           nonlinearity=header_nonlinearity(hdr), grow=grow,
                           refmask=refmask)
    if ceiling_flags is not None:
        sat |= ceiling_flags
    if refpix != "none" and refmask.any():
        from scenesim.calib.refpix import correct_reference
        e = np.asarray(correct_reference(e, det, scheme=refpix), dtype=np.float32)
    nl = header_nonlinearity(hdr) if linearize else None
    if nl is not None:
        e = linearize_resultants(e, nl, tbar)
    if ro.reset_mode == "global":
        times = ro.read_times(t_frame, det.pixel_time())
    else:
        times = ro.read_times(t_frame)
    output_of_column = np.asarray(det.output_of_column()).reshape(-1)
    if remove_common_mode:
        outputs = np.broadcast_to(output_of_column, det.shape).astype(np.intp)
        offsets = common_mode(e, times, read_noise=rdn_model, groups=outputs,
                              saturated=sat, refmask=refmask, threads=threads)
        # (nints, nres, n_out) -> (nints, nres, 1, nx): each column its output's
        e -= offsets[:, :, None, output_of_column].astype(np.float32)
    rn_fit = rdn_model
    if measure_noise:
        columns = np.broadcast_to(np.arange(det.nx), det.shape)
        rn_fit = measure_read_noise(e, times, read_noise=rdn_model, groups=columns,
                                    saturated=sat, refmask=refmask, threads=threads)
    cards = [exposure_card(exp.name),
             ("REFPIX", refpix, "reference-pixel correction"),
             ("RNCONV", "per read", "read noise convention: per read, not CDS"),
             ("RNMODEL", float(rdn_model), "[e-] model white read noise per read"),
             ("RNSOURCE", "measured" if measure_noise else "model",
              "RNOISE: per-column measured or model"),
             ("CMREMOVE", bool(remove_common_mode), "per-output common mode removed"),
             ("IPCDECON", bool(decon), "IPC kernel (IPCKERN) deconvolved"),
             ("IPCRNFAC", float(rn_gain), "read noise x this by the IPC deconvolution"),
             ("LINCORR", nl is not None, "classical nonlinearity inverted (NLCOEFF)")]
    for key in COPIED_KEYS:
        if key in hdr:
            cards.append(card(key, hdr[key], hdr.comments[key]))
    return PreparedExposure(
        name=exp.name, header=hdr, detector=det, readout=ro, gain=gain,
        t_frame=t_frame, electrons=e, saturated=sat, read_times=times,
        read_noise=rn_fit, read_noise_model=float(rdn_model), refmask=refmask,
        cards=tuple(cards))


def fit_exposure_file(exposure, output, *, fitter="gls", refpix="jwst",
                      jump_threshold=5.0, read_noise=None, threads=None,
                      overwrite=True, remove_common_mode=True, measure_noise=True,
                      linearize=True, deconvolve_ipc=True):
    """Fit the slopes of ``exposure`` and write them to ``output``.

    Parameters
    ----------
    exposure : str, os.PathLike or scenesim.io.exposure.Exposure
        Exposure file written by scenesim (``SCI`` uint16 DN + ``READS`` table), or
        the same contents in memory (e.g. ``write_exposure(engine, None)
        ["exposure"]``).
    output : str or os.PathLike
        Slope file (see :func:`scenesim.rampfit.fit.write_fit`).
    fitter : {'cds', 'ols', 'gls'}
    refpix : {'none', 'median', 'jwst'}
    jump_threshold : float or None
        Jump detection in sigma; 0 or None turns it off.
    read_noise : float, optional
        Model white read noise, e- per read (not CDS); default the header's
        ``RDNOISE``.
    threads : int or None
        Worker threads (see :func:`scenesim.rampfit.fit.fit_ramps`).
    overwrite : bool
        Replace an existing ``output``.
    remove_common_mode : bool
        Subtract, per output and read, the noise common to the output's pixels that
        the reference correction left (:func:`scenesim.rampfit.fit.common_mode`; see the
        module notes).
    measure_noise : bool
        Rescale the read noise per column to the scatter measured in the ramps
        (:func:`scenesim.rampfit.fit.measure_read_noise`; see the module notes).  False:
        use ``read_noise`` as it is.
    linearize : bool
        Invert the classical nonlinearity recorded in the header (``NLCOEFF``).
    deconvolve_ipc : bool
        Undo the IPC kernel recorded in the header (``IPCKERN``) first (see
        :func:`prepare_exposure`); the slope file records it (``IPCDECON``,
        ``IPCKERN``, ``IPCRNFAC``).

    Returns
    -------
    scenesim.rampfit.fit.FitResult

    Raises
    ------
    noise.errors.ParameterError
        Bad parameter or unwritable ``output``, before any work.
    noise.errors.FileFormatError
        Missing or malformed exposure.
    """
    if fitter not in FITTERS:
        raise ParameterError(f"'fitter' must be one of {list(FITTERS)}, got {fitter!r}")
    if jump_threshold is not None and (
            isinstance(jump_threshold, bool)
            or not isinstance(jump_threshold, numbers.Real)
            or not math.isfinite(jump_threshold) or jump_threshold < 0):
        raise ParameterError(
            f"'jump_threshold' must be None, 0 (off) or a finite number > 0 (sigma), "
            f"got {jump_threshold!r}")
    _check_prepare_args(refpix, read_noise, remove_common_mode, measure_noise, threads,
                        deconvolve_ipc)
    from noise.validate import check_writable
    check_writable("output", output, overwrite=overwrite)
    prep = prepare_exposure(exposure, refpix=refpix, read_noise=read_noise,
                            remove_common_mode=remove_common_mode,
                            measure_noise=measure_noise, threads=threads,
                            linearize=bool(linearize), deconvolve_ipc=deconvolve_ipc)
    result = fit_ramps(prep.electrons, prep.read_times, read_noise=prep.read_noise,
                       gain=prep.gain, fitter=fitter, saturated=prep.saturated,
                       jump_threshold=jump_threshold or None, refmask=prep.refmask,
                       threads=threads)
    cards = list(prep.cards)
    cards.insert(2, ("JUMPTHR", float(jump_threshold or 0.0),
                     "[sigma] jump threshold, 0=off"))
    write_fit(output, result, header_cards=cards, overwrite=overwrite)
    return result
