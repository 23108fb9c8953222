"""Level-1 preparation of an exposure before any ramp fitter, and the fit of its file.

:func:`prepare_exposure` is the one pre-processing of an exposure before any fitter:
it takes an exposure file (JWST uncal layout, see :mod:`scenesim.io.exposure`) or the
same contents in memory (:class:`scenesim.io.exposure.Exposure`, e.g. from a run
that writes no ramp file) and returns a :class:`PreparedExposure`.
:func:`fit_exposure_file` fits its slopes (:func:`scenesim.rampfit.fit_ramps`) and
writes the slope file (:mod:`scenesim.io.fitfile`);
:func:`scenesim.adapters.stcal.fit_exposure_stcal` hands the very same arrays to
stcal, so that comparing the two isolates the fitter.  What is done is chosen with
one :class:`PrepareOptions`.

Steps, in order
---------------
1. DN to electrons with the header's ``GAIN``.
2. IPC undone on every resultant of the whole frame when the header records its
   kernel (``IPCKERN``; :func:`scenesim.detector.ipc.undo_ipc`, see below).
3. Saturation flags (:mod:`scenesim.calib.saturation`, from the header's
   ``FULLWELL``, ``NLCOEFF``, ``RDNOISE`` and ADC ceiling ``(2^ADCBITS - 1) GAIN``),
   judged on the ramps in e- before the reference correction, as the JWST
   pipeline's saturation step precedes its reference-pixel step.
4. Reference-pixel correction (:mod:`scenesim.calib.refpix`).
5. Inversion of the classical nonlinearity recorded in the header (``NLCOEFF``,
   :func:`scenesim.detector.nonlinearity.linearize_resultants`).
6. Removal of the per-output common mode (:func:`scenesim.calib.noise_model.common_mode`,
   on at most 64 rows), estimated on the corrected ramps.
7. The effective read noise per column (:func:`scenesim.calib.noise_model.measure_read_noise`,
   on at most 256 rows), measured on the ramps without the common mode.

Noise model from the data (:mod:`scenesim.calib.noise_model`): the header's
``RDNOISE`` is the white noise of **one read** (e-, not CDS), but after the
reference correction the ramps also carry (i) noise common to all pixels of an
output, read by read, and (ii) residual row banding.  (i) is a slow wander of every
ramp of the output, which the GLS jump test (a step test) flags as jumps; it is
estimated from the regular pixels and subtracted, except its mean rate, which cannot
be told from a uniform background.  (ii) is white in each pixel's ramp and depends
on the column (the time within the row at which the pixel is read): the read noise
is rescaled per column so that the median ``chi2`` of read-noise dominated pixels is
that of a right model.  The slope file records the model value (``RNMODEL``), the
median fitted value (``RNOISE``) and whether the corrections ran (``RNSOURCE``,
``CMREMOVE``).  Caveat: the common mode is estimated from a finite number of pixels,
and its removal moves all slopes of an output together by the estimate's error;
analyses that need independent pixels should set ``remove_common_mode=False``.

IPC is undone before the flags and the linearisation
----------------------------------------------------
The engine reads ``F K(p(q))`` (flat ``F``, IPC kernel ``K``, nonlinearity ``p``,
charge ``q``).  Inverting ``p`` pixel by pixel on that signal mixes ``p`` of
neighbours that hold different charges.  ``K`` is linear, so ``K^-1`` of a resultant
is exactly the mean over its reads of ``p(q)``; the linearisation then inverts ``p``
(with the reads' spread within a multi-read resultant taken out, from the read
times).  :func:`undo_ipc` is the exact inverse of
:func:`scenesim.detector.ipc.apply_ipc`, edges included (the engine applies IPC to
the reference pixels too, so they get back to their own signal), iterated to 1e-3
of the noise of one read, ``sqrt(RDNOISE^2 + GAIN^2 / 12)``.  The fit then reports
each pixel's *own* rate (truth ``RATE`` without a flat; ``K^-1`` of ``RATE_IPC`` in
general), not ``RATE_IPC``.  Consequences:

* saturation: a full pixel reads exactly ``p(FW)`` above its zero level, and its
  neighbours no longer bend when it stops collecting, so flags are **not** grown to
  the 3 x 3 neighbours (``grow = 1``, as JWST's ``n_pix_grow_sat``, stays for IPC
  that is not undone: ``deconvolve_ipc=False``, or a file with ``IPC`` but without
  ``IPCKERN``).  The ADC clip is not linear (``K^-1`` would spread a clipped
  pixel's error, ``alpha`` of the clipped signal, into its neighbours): it is tested
  on the raw ramps and its flags are grown to the 3 x 3 box;
* noise: white read noise, added after IPC, comes out amplified by ``g = sqrt(sum
  (K^-1)^2)`` (:func:`ipc_noise_gain`: 1.065 for ``alpha = 1.5 %``) and slightly
  anticorrelated between neighbours; the model read noise is multiplied by ``g``
  (``RNMODEL``; ``IPCRNFAC`` records ``g``) and the measured one follows the data.
  Shot noise, drawn before IPC, comes back white, with the variance of the pixel's
  own rate, which is what the fitter assumes;
* flat field: a quantum efficiency, already in the collected charge (it scales the
  light before the Poisson draws), so undoing IPC gives each pixel's own charge, the
  flat included: the fit recovers ``K^-1 RATE_IPC = RATE``.

Measurements of each step on the example scenes (bias, ``chi2``, flags, cost) are
in ``docs/VALIDATION_FIT.md``.
"""

import math
import os
from dataclasses import dataclass

import numpy as np
from astropy.io import fits

from noise.clock import Detector, detector_from_header
from noise.errors import ParameterError
from noise.validate import check_bool, check_choice, check_float, check_int, check_writable

from scenesim.calib.noise_model import common_mode, measure_read_noise
from scenesim.calib.refpix import (SCHEMES, check_correction_options, correct_irs2,
                                   correct_reference)
from scenesim.calib.saturation import SaturationOptions, saturation_flags
from scenesim.detector.ipc import ipc_noise_gain, undo_ipc
from scenesim.detector.nonlinearity import linearize_resultants
from scenesim.detector.readout import Readout
from scenesim.io.exposure import Exposure, raw_resultants
from scenesim.io.fitfile import write_fit
from scenesim.io.header import (exposure_read_noise, exposure_readout,
                                exposure_settings, header_ipc_kernel, header_nonlinearity,
                                preparation_cards)
from scenesim.rampfit.fitter import FITTERS, fit_ramps

__all__ = ["PrepareOptions", "PreparedExposure", "prepare_exposure", "load_exposure",
           "fit_exposure_file"]

#: Truncation error of the IPC deconvolution in :func:`prepare_exposure`, as a
#: fraction of the noise of one read (white read noise and ADC quantisation).
_IPC_TOLERANCE = 1e-3


def _optional(check, name, value, none_means, **limits):
    """``None``, or ``check(name, value, **limits)`` with ``None``'s meaning named."""
    if value is None:
        return None
    try:
        return check(name, value, **limits)
    except ParameterError as exc:
        raise ParameterError(f"{exc}; or None ({none_means})") from exc


@dataclass(frozen=True)
class PrepareOptions:
    """What :func:`prepare_exposure` does to an exposure, validated once.

    Parameters
    ----------
    refpix : {'jwst', 'median', 'none', 'irs2'}
        Reference-pixel correction (:func:`scenesim.calib.refpix.correct_reference`;
        ``'irs2'``: :func:`scenesim.calib.refpix.correct_irs2` on the exposure's
        ``SCI`` and ``RAWREF``, for an IRS2 detector).
    read_noise : float or None
        Model white read noise, e- per read (not CDS), >= 0; None: the header's
        ``RDNOISE``.
    remove_common_mode : bool
        Subtract, per output and read, the noise common to the output's pixels that
        the reference correction left (:func:`scenesim.calib.noise_model.common_mode`).
    measure_noise : bool
        Rescale the read noise per column to the scatter measured in the ramps
        (:func:`scenesim.calib.noise_model.measure_read_noise`); False:
        ``read_noise`` (or ``RDNOISE``) as it is.
    threads : int or None
        Worker threads (>= 1) of the IPC deconvolution, the common-mode and
        read-noise fits and the slope fit; None: ``min(os.cpu_count(), 8)``.
    linearize : bool
        Invert the classical nonlinearity recorded in the header (``NLCOEFF``;
        no-op when there is none).
    deconvolve_ipc : bool
        Undo the IPC kernel recorded in the header (``IPCKERN``; no-op when there is
        none): the slopes are then each pixel's own rate (``K^-1`` of the truth's
        ``RATE_IPC``).  False: the ramps keep IPC, the slopes estimate
        ``RATE_IPC``, and the saturation flags are grown to the 3 x 3 neighbours.
    """

    refpix: str = "jwst"
    read_noise: object = None
    remove_common_mode: bool = True
    measure_noise: bool = True
    threads: object = None
    linearize: bool = True
    deconvolve_ipc: bool = True

    def __post_init__(self):
        check_choice("refpix", self.refpix, SCHEMES)
        object.__setattr__(self, "read_noise", _optional(
            check_float, "read_noise", self.read_noise,
            "the header's RDNOISE, e- per read, not CDS", minimum=0.0))
        for name in ("remove_common_mode", "measure_noise", "linearize",
                     "deconvolve_ipc"):
            object.__setattr__(self, name, check_bool(name, getattr(self, name)))
        object.__setattr__(self, "threads", _optional(
            check_int, "threads", self.threads, "up to 8 cores", minimum=1))


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
        Saturated resultants (:func:`scenesim.calib.saturation.saturation_flags`;
        sticky within an integration).
    read_times : list of ngroups ndarrays, s from each pixel's reset
        Read times of every resultant: ``(N_i,)`` for a rolling reset, ``(N_i, ny,
        nx)`` for a global reset (see
        :meth:`scenesim.detector.readout.Readout.read_times`).
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


def _check_options(options):
    if not isinstance(options, PrepareOptions):
        raise ParameterError(
            f"'options' must be a scenesim.calib.prepare.PrepareOptions, got "
            f"{type(options).__name__}")
    return options


def prepare_exposure(exposure, *, options=PrepareOptions()):
    """Read an exposure and make its ramps ready for a fitter (module notes).

    Parameters
    ----------
    exposure : str, os.PathLike or scenesim.io.exposure.Exposure
        Exposure file written by scenesim (``SCI`` uint16 DN (nints, ngroups, ny,
        nx) + ``READS`` table), or the same contents in memory.
    options : PrepareOptions, keyword-only
        The steps to run and their settings (default: every step, the header's
        read noise, the ``'jwst'`` reference correction).

    Returns
    -------
    PreparedExposure

    Raises
    ------
    noise.errors.ParameterError
        ``options`` is not a :class:`PrepareOptions` (before the exposure is read),
        or a recorded kernel that keeps half of the charge or less in its centre
        (it cannot be undone by the iteration) with ``deconvolve_ipc`` true.
    noise.errors.FileFormatError
        Missing or malformed exposure.
    """
    _check_options(options)
    exp = load_exposure(exposure)
    ro = exposure_readout(exp)
    if ro.ngroups < 2:
        raise ParameterError(
            f"exposure {exp.name!r} has one group (NGROUPS = 1): there is no slope to "
            f"fit (a one-group exposure only gives a zero point)")
    hdr = exp.header
    det = detector_from_header(hdr)
    if options.refpix == "irs2":              # needs interleaved reference samples
        check_correction_options(det, "irs2", 11, 3.0)
    cfg = exposure_settings(hdr)
    gain, t_frame = cfg["gain"], cfg["t_frame"]
    rdn = exposure_read_noise(hdr) if options.read_noise is None else options.read_noise
    e = exp.sci.astype(np.float32) * np.float32(gain)
    tbar = ro.mean_times(t_frame)
    refmask = det.reference_mask()
    kernel = header_ipc_kernel(hdr)          # None: no IPC, identity or not recorded
    decon = options.deconvolve_ipc and kernel is not None
    sat, rn_gain = _undo_ipc_and_flag_saturation(e, exp.name, hdr, cfg, ro, tbar,
                                                 kernel, decon, rdn, refmask,
                                                 options.threads)
    rdn_model = rdn * rn_gain
    if options.refpix == "irs2":
        # every sample read (RAWREF too), the image pixels as prepared so far
        raw = raw_resultants(exp, det).astype(np.float32) * np.float32(gain)
        _, _, image_x = det.raw_columns()
        raw[..., image_x >= 0] = e[..., image_x[image_x >= 0]]
        e = np.asarray(correct_irs2(raw, det), dtype=np.float32)
        del raw
    elif options.refpix != "none" and refmask.any():
        e = np.asarray(correct_reference(e, det, scheme=options.refpix),
                       dtype=np.float32)
    nl = header_nonlinearity(hdr) if options.linearize else None
    if nl is not None:
        e = linearize_resultants(e, nl, tbar, read_times=ro.read_times(t_frame),
                                 saturated=sat)
    if ro.reset_mode == "global":
        times = ro.read_times(t_frame, det.pixel_time())
    else:
        times = ro.read_times(t_frame)
    e, rn_fit = _noise_from_data(e, times, det, sat, refmask, rdn_model, options)
    cards = preparation_cards(exp.name, hdr, options, rdn_model, decon, rn_gain,
                               nl is not None)
    return PreparedExposure(
        name=exp.name, header=hdr, detector=det, readout=ro, gain=gain,
        t_frame=t_frame, electrons=e, saturated=sat, read_times=times,
        read_noise=rn_fit, read_noise_model=float(rdn_model), refmask=refmask,
        cards=cards)


def _undo_ipc_and_flag_saturation(e, name, hdr, cfg, ro, tbar, kernel, decon, rdn,
                                  refmask, threads):
    """Steps 2-3 on ``e`` (in place): IPC undone when ``decon``, then the saturation
    flags; returns the flags and the read-noise factor of the deconvolution."""
    gain = cfg["gain"]
    ceiling = (2 ** cfg["adc_bits"] - 1) * gain
    t_last = np.array([t[-1] for t in ro.read_times(cfg["t_frame"])])
    n_reads = np.asarray(ro.n_per_resultant)
    rn_gain, ceiling_flags = 1.0, None
    if decon:
        # the ADC clip is not linear: judged on the raw ramps, and grown to the 3 x 3
        # box (undoing IPC spreads a clipped pixel's error into its neighbours)
        if np.any(t_last > tbar) or float(e.max()) >= ceiling:
            ceiling_flags = saturation_flags(
                e, tbar, SaturationOptions(0.0, ceiling, grow=1), t_last=t_last,
                n_reads=n_reads)
        _undo_recorded_ipc(e, kernel, name, rdn, gain, threads)
        rn_gain = ipc_noise_gain(kernel)
    # growth hides the bend that a saturating pixel puts in its neighbours through
    # IPC; not needed once IPC is undone
    grow = 1 if not decon and (kernel is not None or cfg["ipc_unrecorded"]) else 0
    sat = saturation_flags(
        e, tbar, SaturationOptions(cfg["full_well"], ceiling, read_noise=rdn * rn_gain,
                                   nonlinearity=header_nonlinearity(hdr), grow=grow),
        t_last=t_last, n_reads=n_reads, refmask=refmask)
    if ceiling_flags is not None:
        sat |= ceiling_flags
    return sat, rn_gain


def _undo_recorded_ipc(e, kernel, name, read_noise, gain, threads):
    """Undo the header's IPC kernel on ``e`` in place, to 1e-3 of one read's noise."""
    tolerance = _IPC_TOLERANCE * math.hypot(read_noise, gain / math.sqrt(12))
    try:
        undo_ipc(e, kernel, tolerance=tolerance, out=e,
                 threads=min(os.cpu_count() or 1, 8) if threads is None else threads)
    except ParameterError as exc:
        raise ParameterError(
            f"exposure {name!r}: its IPC kernel (IPCKERN) cannot be "
            f"deconvolved ({exc}); pass deconvolve_ipc=False") from exc


def _noise_from_data(e, times, det, sat, refmask, rdn_model, options):
    """Common mode removed from ``e`` and the read noise to fit with (steps 6-7)."""
    output_of_column = np.asarray(det.output_of_column()).reshape(-1)
    if options.remove_common_mode:
        outputs = np.broadcast_to(output_of_column, det.shape).astype(np.intp)
        offsets = common_mode(e, times, read_noise=rdn_model, groups=outputs,
                              saturated=sat, refmask=refmask, threads=options.threads)
        # (nints, nres, n_out) -> (nints, nres, 1, nx): each column its output's
        e -= offsets[:, :, None, output_of_column].astype(np.float32)
    if not options.measure_noise:
        return e, rdn_model
    columns = np.broadcast_to(np.arange(det.nx), det.shape)
    return e, measure_read_noise(e, times, read_noise=rdn_model, groups=columns,
                                 saturated=sat, refmask=refmask,
                                 threads=options.threads)


def fit_exposure_file(exposure, output, *, fitter="gls", jump_threshold=5.0,
                      overwrite=False, options=PrepareOptions()):
    """Fit the slopes of ``exposure`` and write them to ``output``.

    Parameters
    ----------
    exposure : str, os.PathLike or scenesim.io.exposure.Exposure
        Exposure file written by scenesim (``SCI`` uint16 DN + ``READS`` table), or
        the same contents in memory (e.g. ``write_exposure(engine, None)
        ["exposure"]``).
    output : str or os.PathLike
        Slope file (see :func:`scenesim.io.fitfile.write_fit`).
    fitter : {'cds', 'ols', 'gls'}
    jump_threshold : float or None
        Jump detection in sigma; 0 or None turns it off.
    overwrite : bool
        Replace an existing ``output`` (default: refuse it).
    options : PrepareOptions, keyword-only
        The preparation (:func:`prepare_exposure`); its ``threads`` also run the
        fit.  The slope file records it (``REFPIX``, ``RNSOURCE``, ``CMREMOVE``,
        ``IPCDECON``, ``IPCKERN``, ``IPCRNFAC``, ``LINCORR``).

    Returns
    -------
    scenesim.io.fitfile.FitResult

    Raises
    ------
    noise.errors.ParameterError
        Bad parameter or unwritable ``output``, before any work.
    noise.errors.FileFormatError
        Missing or malformed exposure.
    """
    check_choice("fitter", fitter, FITTERS)
    jump_threshold = _optional(check_float, "jump_threshold", jump_threshold,
                               "0 or None turn detection off", minimum=0.0)
    _check_options(options)
    check_writable("output", output, overwrite=overwrite)
    prep = prepare_exposure(exposure, options=options)
    result = fit_ramps(prep.electrons, prep.read_times, read_noise=prep.read_noise,
                       gain=prep.gain, fitter=fitter, saturated=prep.saturated,
                       jump_threshold=jump_threshold or None, refmask=prep.refmask,
                       threads=options.threads)
    cards = list(prep.cards)
    cards.insert(2, ("JUMPTHR", float(jump_threshold or 0.0),
                     "[sigma] jump threshold, 0=off"))
    write_fit(output, result, header_cards=cards, overwrite=overwrite)
    return result
