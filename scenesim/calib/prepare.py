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
:func:`scenesim.detector.ipc.apply_ipc`, edges included, on the regular pixels (the
reference pixels are not coupled, in the engine or here: the reference correction
sees no signal, and no clipped pixel's error spreads into them), iterated to 1e-3
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

Memory of a fit (:func:`fit_exposure_file`)
-------------------------------------------
:func:`prepare_exposure` holds the whole cube in float32 e- (and its flags).
:func:`fit_exposure_file` instead runs the same steps by frames or rows of a
temporary float32 cube beside the output (``.scenesim-<pid>-*.tmp``, removed on
every exit; one left by a killed process is removed by the next run), keeps the
saturation flags as the first saturated resultant of each pixel, and fits from the
file by row blocks, to the same bits: what it holds does not grow with the number of
resultants, except the noise fits' row subsamples (64 and 256 rows of every
resultant: 1/8 of the cube at 2048 rows, 1/16 at 4096) and the linearisation's
batch (``nints`` x 2 frames at least).  The ``'irs2'`` correction (each reference
sample's mean over the groups), compressed files and float64 ``SCI`` still take
the whole cube.
Measured in BENCHMARKS.md ("The fit's scaling").

Measurements of each step on the example scenes (bias, ``chi2``, flags, cost) are
in ``docs/VALIDATION_FIT.md``.
"""

import contextlib
import dataclasses
import math
import os
from dataclasses import dataclass

import numpy as np
from astropy.io import fits

from noise.adc import averaging_noise
from noise.clock import Detector, detector_from_header
from noise.errors import FileFormatError, ParameterError, ScenesimError
from noise.fitsio import input_path, is_gzip_file, output_error, temp_file
from noise.validate import check_bool, check_choice, check_float, check_int, check_writable

from scenesim.calib.noise_model import common_mode, measure_read_noise
from scenesim.calib.refpix import SCHEMES, applied_scheme, correct_irs2, correct_reference
from scenesim.calib.saturation import (SaturationOptions, saturation_flags,
                                       zero_level_bound)
from scenesim.detector.ipc import ipc_noise_gain, undo_ipc
from scenesim.detector.nonlinearity import linearize_resultants
from scenesim.detector.nonlinearity import _PIXELS as _LINEARIZE_PIXELS  # its blocks
from scenesim.detector.readout import Readout
from scenesim.io.cuberows import NpyCube, exposure_rows
from scenesim.io.exposure import Exposure, raw_resultants, read_exposure_header
from scenesim.io.fitfile import write_fit
from scenesim.io.header import (exposure_read_noise, exposure_readout,
                                exposure_settings, header_ipc_kernel, header_nonlinearity,
                                preparation_cards)
from scenesim.rampfit.fitter import FITTERS, fit_ramps

__all__ = ["PrepareOptions", "PreparedExposure", "prepare_exposure", "load_exposure",
           "fit_exposure_file", "rounding_noise"]

#: Rows of the common-mode and read-noise fits (every ``ceil(ny / rows)``-th row).
_CM_ROWS, _RN_ROWS = 64, 256
#: Values (float32) of a block of frames or rows read at once by the streamed
#: preparation (:func:`fit_exposure_file`): 32 MB; and of the batches of
#: resultants linearised at once (at least two frames of every integration).
_BLOCK_VALUES, _LINEARIZE_VALUES = 1 << 23, 1 << 25

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
    resultant_noise : ndarray, shape (ngroups,), float64, e- rms
        White noise of each resultant beyond its reads' (:func:`rounding_noise`):
        the rounding of the on-board mean of its digitised reads, times the IPC
        factor; zeros for floating-point data.
    refmask : ndarray of bool, shape (ny, nx)
        Reference pixels.
    cards : tuple of (str, value, str)
        FITS cards recording the exposure and what was done to it (``EXPOSURE``,
        ``REFPIX``, ``RNCONV``, ``RNMODEL``, ``RNSOURCE``, ``CMREMOVE``,
        ``IPCDECON``: IPC undone, ``IPCRNFAC``: the read-noise factor that came with
        it (1 if not), ``RSNOISE``: the largest ``resultant_noise``, ``LINCORR``)
        and the exposure keywords copied from its header
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
    resultant_noise: np.ndarray
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


def _exposure_setup(exp, options):
    """``(readout, header, detector, settings, read noise e-, options)`` of an
    exposure to fit; a one-group exposure, or a reference correction its readout
    cannot support, is refused.  The returned options carry the correction applied
    (:func:`scenesim.calib.refpix.applied_scheme`: ``'jwst'`` on a window with no
    reference pixel is ``'none'``)."""
    ro = exposure_readout(exp)
    if ro.ngroups < 2:
        raise ParameterError(
            f"exposure {exp.name!r} has one group (NGROUPS = 1): there is no slope to "
            f"fit (a one-group exposure only gives a zero point)")
    hdr = exp.header
    det = detector_from_header(hdr)
    try:
        scheme = applied_scheme(det, options.refpix)
    except ParameterError as exc:
        raise ParameterError(f"exposure {exp.name!r}: {exc}") from exc
    if scheme != options.refpix:
        options = dataclasses.replace(options, refpix=scheme)
    rdn = exposure_read_noise(hdr) if options.read_noise is None else options.read_noise
    return ro, hdr, det, exposure_settings(hdr), rdn, options


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
    ro, hdr, det, cfg, rdn, options = _exposure_setup(exp, options)
    gain, t_frame = cfg["gain"], cfg["t_frame"]
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
    q = rounding_noise(exp.sci.dtype, ro, gain) * rn_gain
    e, rn_fit = _noise_from_data(e, times, det, sat, refmask, rdn_model, q, options)
    cards = preparation_cards(exp.name, hdr, options, rdn_model, decon, rn_gain,
                               nl is not None, q)
    return PreparedExposure(
        name=exp.name, header=hdr, detector=det, readout=ro, gain=gain,
        t_frame=t_frame, electrons=e, saturated=sat, read_times=times,
        read_noise=rn_fit, read_noise_model=float(rdn_model), resultant_noise=q,
        refmask=refmask, cards=cards)


def rounding_noise(dtype, readout, gain):
    """e- rms per resultant that the on-board rounding of the mean of its reads
    added (:func:`noise.adc.averaging_noise`), for data stored as ``dtype``: zeros
    unless integers (DN), where a resultant of ``N > 1`` reads is a rounded mean."""
    if np.dtype(dtype).kind not in "iu":
        return np.zeros(readout.ngroups)
    return averaging_noise(gain, readout.n_per_resultant)


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
        _undo_recorded_ipc(e, kernel, name, rdn, gain, threads, refmask)
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


def _undo_recorded_ipc(e, kernel, name, read_noise, gain, threads, refmask):
    """Undo the header's IPC kernel on ``e`` in place, to 1e-3 of one read's noise,
    on the regular pixels (the reference pixels are not coupled:
    :mod:`scenesim.detector.ipc`)."""
    tolerance = _IPC_TOLERANCE * math.hypot(read_noise, gain / math.sqrt(12))
    try:
        undo_ipc(e, kernel, tolerance=tolerance, out=e, refmask=refmask,
                 threads=min(os.cpu_count() or 1, 8) if threads is None else threads)
    except ParameterError as exc:
        raise ParameterError(
            f"exposure {name!r}: its IPC kernel (IPCKERN) cannot be "
            f"deconvolved ({exc}); pass deconvolve_ipc=False") from exc


def _noise_from_data(e, times, det, sat, refmask, rdn_model, q, options):
    """Common mode removed from ``e`` and the read noise to fit with (steps 6-7),
    with the resultants' own white noise ``q`` (e- rms) in the model."""
    output_of_column = np.asarray(det.output_of_column()).reshape(-1)
    if options.remove_common_mode:
        outputs = np.broadcast_to(output_of_column, det.shape).astype(np.intp)
        offsets = common_mode(e, times, read_noise=rdn_model, groups=outputs,
                              saturated=sat, refmask=refmask, threads=options.threads,
                              max_rows=_CM_ROWS, resultant_noise=q)
        # (nints, nres, n_out) -> (nints, nres, 1, nx): each column its output's
        e -= offsets[:, :, None, output_of_column].astype(np.float32)
    if not options.measure_noise:
        return e, rdn_model
    columns = np.broadcast_to(np.arange(det.nx), det.shape)
    return e, measure_read_noise(e, times, read_noise=rdn_model, groups=columns,
                                 saturated=sat, refmask=refmask,
                                 threads=options.threads, max_rows=_RN_ROWS,
                                 resultant_noise=q)


class _Source:
    """The ``SCI`` cube of an exposure in e- (``DN.astype(float32) * float32(GAIN)``,
    as :func:`prepare_exposure`), read by frames or rows: from its file (positioned
    reads, :func:`scenesim.io.cuberows.exposure_rows`) or from an in-memory
    :class:`Exposure`.  ``exposure`` is an :class:`Exposure` whose ``sci`` may be a
    stand-in of the right shape (for :func:`exposure_readout`)."""

    def __init__(self, exposure, gain, rows=None):
        self.exposure, self.gain, self._rows = exposure, np.float32(gain), rows
        self.shape = exposure.sci.shape

    def frames(self, k, r0, r1):
        if self._rows is not None:
            return self._rows.frames(k, r0, r1)
        return self.exposure.sci[k, r0:r1].astype(np.float32) * self.gain

    def rows(self, y0, y1):
        if self._rows is not None:
            return self._rows.rows(y0, y1)
        return self.exposure.sci[:, :, y0:y1].astype(np.float32) * self.gain


def _open_source(exposure):
    """A :class:`_Source` of ``exposure`` (path or :class:`Exposure`), or None for a
    file that cannot be read by blocks (compressed)."""
    if isinstance(exposure, Exposure):
        gain = exposure_settings(exposure.header)["gain"]
        return _Source(exposure, gain)
    if not isinstance(exposure, (str, os.PathLike)):
        return None                              # prepare_exposure says why
    path = input_path(exposure, "exposure")
    if str(path).lower().endswith(".gz") or is_gzip_file(path):   # X.FITS.GZ too
        return None
    header, reads = read_exposure_header(path)
    gain = exposure_settings(header)["gain"]
    if gain is None or not (math.isfinite(gain) and gain > 0):
        raise FileFormatError(f"exposure {os.fspath(path)!r}: its header card GAIN = "
                              f"{header.get('GAIN')!r} e-/DN must be a finite number > 0")
    rows = exposure_rows(path, gain=gain)
    if rows.dtype != np.float32:
        # float64 data would be scaled in float64, not as astype(float32) * gain
        return None
    # (rows.all_finite: the file holds integers, DN, whose multi-read resultants
    # are rounded means: rounding_noise reads it from the stand-in's dtype)
    stand_in = np.broadcast_to(np.uint16(0) if rows.all_finite else np.float32(0),
                               rows.shape)
    return _Source(Exposure(stand_in, header, reads, os.fspath(path)), gain, rows)


class _FirstSaturated:
    """Sticky saturation flags kept as the first saturated resultant of each pixel
    and integration ((nints, ny, nx); ``nres`` when none), a row source of bool
    blocks (nints, nres, rows, nx) for :func:`scenesim.rampfit.fit_ramps`."""

    dtype = np.dtype(bool)

    def __init__(self, first, nres):
        self.first, self.nres = first, nres
        self.shape = (first.shape[0], nres) + first.shape[1:]

    def rows(self, y0, y1):
        return self.take(slice(y0, y1))

    def take(self, rows):
        """Flags of the rows ``rows`` (a slice or an index array)."""
        return np.arange(self.nres)[None, :, None, None] >= self.first[:, None, rows]


class _CorrectedRows:
    """Rows of the prepared cube (a file) less the common mode of each output."""

    all_finite = False

    def __init__(self, cube, offsets, output_of_column):
        self.cube, self.shape, self.dtype = cube, cube.shape, cube.dtype
        self._off = None if offsets is None else \
            offsets[:, :, None, output_of_column].astype(np.float32)

    def rows(self, y0, y1):
        return self.take(self.cube.rows(y0, y1))

    def take(self, block):
        if self._off is not None:
            block -= self._off
        return block


def _row_blocks(ny, per_row):
    """Row bounds of blocks of about :data:`_BLOCK_VALUES` values (``per_row`` a row)."""
    step = max(1, _BLOCK_VALUES // max(per_row, 1))
    return [(y, min(y + step, ny)) for y in range(0, ny, step)]


def _gather_rows(cube, rows):
    """Rows ``rows`` of every integration and resultant of ``cube``, stacked."""
    nints, nres, _, nx = cube.shape
    out = np.empty((nints, nres, len(rows), nx), cube.dtype)
    for i, y in enumerate(rows):
        out[:, :, i:i + 1] = cube.rows(y, y + 1)
    return out


def _prepare_to_file(src, path, options):
    """:func:`prepare_exposure` with every step by frames or rows of a float32 cube in
    the file ``path`` (steps 1-5; 6-7 on their row subsamples).

    Same values as :func:`prepare_exposure` to the last bit: each step is applied
    to the same unit it is in memory (IPC undo and the reference correction per
    frame, the linearisation per resultant over every integration's whole frame with
    the zero level from resultants 0 and 1, the saturation tests per pixel with the
    zero-level bound of the whole frames, the noise fits on the same row
    subsamples).  Held at once: a block of frames or rows (~32 MB, or ``threads``
    frames), the linearisation's ``nints x (2 + batch)`` frames and their float64
    zero level, the flags as one first-saturated index per pixel, and the noise
    fits' row subsamples (64 and 256 rows of every resultant).

    Returns ``(prep, resultants, saturated)``: a :class:`PreparedExposure` whose
    ``electrons`` and ``saturated`` are None, and the row sources of the prepared
    resultants (common mode removed as read) and of the flags.
    """
    exp = src.exposure
    ro, hdr, det, cfg, rdn, options = _exposure_setup(exp, options)
    gain, t_frame = cfg["gain"], cfg["t_frame"]
    tbar = ro.mean_times(t_frame)
    refmask = det.reference_mask()
    kernel = header_ipc_kernel(hdr)
    decon = options.deconvolve_ipc and kernel is not None
    threads = min(os.cpu_count() or 1, 8) if options.threads is None else options.threads
    nints, nres, ny, nx = src.shape
    cube = NpyCube.create(path, src.shape)
    # 1-2: e-, IPC undone, frame by frame
    batch = max(threads, 1)
    for k in range(nints):
        for r0 in range(0, nres, batch):
            f = src.frames(k, r0, min(r0 + batch, nres))
            if decon:
                _undo_recorded_ipc(f, kernel, exp.name, rdn, gain, threads, refmask)
            cube.write_frames(k, r0, f)
    rn_gain = ipc_noise_gain(kernel) if decon else 1.0
    # 3: saturation flags by row blocks (halo for the growth)
    first = _saturation_by_rows(src, cube, hdr, cfg, ro, tbar, kernel, decon,
                                rdn * rn_gain, refmask)
    sat = _FirstSaturated(first, nres)
    # 4: reference correction, frame by frame
    if options.refpix != "none" and refmask.any():
        step = max(1, _BLOCK_VALUES // (ny * nx))
        for k in range(nints):
            for r0 in range(0, nres, step):
                f = cube.frames(k, r0, min(r0 + step, nres))
                cube.write_frames(k, r0, np.asarray(
                    correct_reference(f, det, scheme=options.refpix), dtype=np.float32))
    # 5: linearisation, per resultant over all integrations, zero from 0 and 1
    nl = header_nonlinearity(hdr) if options.linearize else None
    if nl is not None:
        _linearize_file(cube, nl, tbar, ro.read_times(t_frame), first)
    if ro.reset_mode == "global":
        times = ro.read_times(t_frame, det.pixel_time())
    else:
        times = ro.read_times(t_frame)
    rdn_model = rdn * rn_gain
    q = rounding_noise(exp.sci.dtype, ro, gain) * rn_gain
    offsets, rn_fit = _noise_from_file(cube, times, det, sat, refmask, rdn_model, q,
                                       options)
    cards = preparation_cards(exp.name, hdr, options, rdn_model, decon, rn_gain,
                              nl is not None, q)
    prep = PreparedExposure(
        name=exp.name, header=hdr, detector=det, readout=ro, gain=gain,
        t_frame=t_frame, electrons=None, saturated=None, read_times=times,
        read_noise=rn_fit, read_noise_model=float(rdn_model), resultant_noise=q,
        refmask=refmask, cards=cards)
    ooc = np.asarray(det.output_of_column()).reshape(-1)
    return prep, _CorrectedRows(cube, offsets, ooc), sat


def _saturation_by_rows(src, cube, hdr, cfg, ro, tbar, kernel, decon, rdn, refmask):
    """Step 3 of :func:`_prepare_to_file`: the first saturated resultant (nints, ny,
    nx) int32, as :func:`_undo_ipc_and_flag_saturation` flags them."""
    nints, nres, ny, nx = cube.shape
    gain = cfg["gain"]
    ceiling = (2 ** cfg["adc_bits"] - 1) * gain
    t_last = np.array([t[-1] for t in ro.read_times(cfg["t_frame"])])
    n_reads = np.asarray(ro.n_per_resultant)
    grow = 1 if not decon and (kernel is not None or cfg["ipc_unrecorded"]) else 0
    opts = SaturationOptions(cfg["full_well"], ceiling, read_noise=rdn,
                             nonlinearity=header_nonlinearity(hdr), grow=grow)
    bound = zero_level_bound(np.stack([cube.frames(k, 0, 2) for k in range(nints)]),
                             tbar, refmask=refmask, nsigma=opts.nsigma)
    lead = bool(np.any(t_last > tbar))
    first = np.empty((nints, ny, nx), np.int32)
    for y0, y1 in _row_blocks(ny, nints * nres * nx):
        a, b = max(0, y0 - grow), min(ny, y1 + grow)
        flags = saturation_flags(cube.rows(a, b), tbar, opts, t_last=t_last,
                                 n_reads=n_reads, refmask=refmask[a:b],
                                 zero_bound=bound)[:, :, y0 - a:y1 - a]
        if decon:
            # the ADC clip, judged on the raw ramps and grown to the 3 x 3 box
            a, b = max(0, y0 - 1), min(ny, y1 + 1)
            raw = src.rows(a, b)
            if lead or float(raw.max()) >= ceiling:
                flags |= saturation_flags(
                    raw, tbar, SaturationOptions(0.0, ceiling, grow=1), t_last=t_last,
                    n_reads=n_reads)[:, :, y0 - a:y1 - a]
        first[:, y0:y1] = np.where(flags.any(axis=1), flags.argmax(axis=1), nres)
    return first


def _linearize_file(cube, nl, tbar, groups, first):
    """Step 5 on the cube file: :func:`linearize_resultants` of resultants 0 and 1
    with a batch of the others, so that each resultant is inverted over the same
    whole frames (every integration) with the same zero level as on the whole cube.
    With multi-read resultants (``groups``: the read times) each pixel's whole ramp
    is needed (its rate): blocks of rows, of the size the function itself works in,
    so the bits are those of the whole cube; ``first``: first saturated resultant."""
    nints, nres, ny, nx = cube.shape
    if not nl.is_linear and any(np.size(g) > 1 for g in groups):
        rows = max(1, _LINEARIZE_PIXELS // (nints * nx))
        for y0 in range(0, ny, rows):
            y1 = min(y0 + rows, ny)
            sat = np.arange(nres)[None, :, None, None] >= first[:, None, y0:y1]
            cube.write_rows(y0, linearize_resultants(
                cube.rows(y0, y1), nl, tbar, read_times=groups, saturated=sat))
        return
    tbar = np.asarray(tbar)
    batch = max(2, _LINEARIZE_VALUES // (nints * ny * nx))
    head = np.stack([cube.frames(k, 0, 2) for k in range(nints)])
    starts = list(range(2, nres, batch)) or [nres]
    for i, r0 in enumerate(starts):
        r1 = min(r0 + batch, nres)
        stack = head if r1 == r0 else np.concatenate(
            [head, np.stack([cube.frames(k, r0, r1) for k in range(nints)])], axis=1)
        lin = linearize_resultants(stack, nl, np.concatenate([tbar[:2], tbar[r0:r1]]))
        for k in range(nints):
            if i == 0:
                cube.write_frames(k, 0, lin[k, :2])
            if r1 > r0:
                cube.write_frames(k, r0, lin[k, 2:])


def _noise_from_file(cube, times, det, sat, refmask, rdn_model, q, options):
    """Steps 6-7 of :func:`_prepare_to_file` on the same row subsamples as
    :func:`_noise_from_data`: the common-mode offsets (or None) and the read noise."""
    ny, nx = det.shape
    ooc = np.asarray(det.output_of_column()).reshape(-1)

    def subsample(max_rows):
        rows = np.arange(0, ny, -(-ny // max_rows))
        t = [x[:, rows] if np.ndim(x) == 3 else x for x in times]
        return rows, t, sat.take(rows), refmask[rows]

    offsets = None
    if options.remove_common_mode:
        rows, t, s, ref = subsample(_CM_ROWS)
        groups = np.broadcast_to(ooc, (rows.size, nx)).astype(np.intp)
        offsets = common_mode(_gather_rows(cube, rows), t, read_noise=rdn_model,
                              groups=groups, saturated=s, refmask=ref,
                              threads=options.threads, max_rows=rows.size,
                              resultant_noise=q)
    if not options.measure_noise:
        return offsets, rdn_model
    rows, t, s, ref = subsample(_RN_ROWS)
    corrected = _CorrectedRows(cube, offsets, ooc)
    sub = corrected.take(_gather_rows(cube, rows))
    columns = np.broadcast_to(np.arange(nx), (rows.size, nx))
    rn = measure_read_noise(sub, t, read_noise=rdn_model, groups=columns,
                            saturated=s, refmask=ref, threads=options.threads,
                            max_rows=rows.size, resultant_noise=q)
    # a value per column (the model times the column's factor): every row alike
    return offsets, np.ascontiguousarray(np.broadcast_to(rn[0], (ny, nx)))


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
        Slope file (see :func:`scenesim.io.fitfile.write_fit`).  While fitting, the
        prepared resultants are kept in a temporary file beside it (float32: 4
        bytes per sample, twice the exposure's ``SCI``), removed on return (module
        notes, "Memory of a fit"); not for ``'irs2'`` or a compressed exposure.
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
    noise.errors.OutputError
        The slope file or the temporary cube cannot be written (disk full, file-size
        limit), naming ``output``.
    """
    check_choice("fitter", fitter, FITTERS)
    jump_threshold = _optional(check_float, "jump_threshold", jump_threshold,
                               "0 or None turn detection off", minimum=0.0)
    _check_options(options)
    check_writable("output", output, overwrite=overwrite)
    src = None if options.refpix == "irs2" else _open_source(exposure)
    if src is None:                  # IRS2 or a compressed file: the whole cube
        prep = prepare_exposure(exposure, options=options)
        result = fit_ramps(prep.electrons, prep.read_times, read_noise=prep.read_noise,
                           gain=prep.gain, fitter=fitter, saturated=prep.saturated,
                           jump_threshold=jump_threshold or None,
                           refmask=prep.refmask, threads=options.threads,
                           resultant_noise=prep.resultant_noise)
    else:
        try:
            tmp = temp_file(output, tag="prepared")
        except OSError as exc:
            raise output_error(output, exc) from exc
        try:
            try:
                prep, resultants, saturated = _prepare_to_file(src, tmp, options)
            except OSError as exc:        # the temporary cube: disk full, size limit
                if isinstance(exc, ScenesimError):
                    raise
                nbytes = 4 * int(np.prod(src.shape))
                raise output_error(output, exc, what=(
                    f"first its prepared ramps, a temporary float32 cube of {nbytes} "
                    f"bytes beside it")) from exc
            result = fit_ramps(resultants, prep.read_times, read_noise=prep.read_noise,
                               gain=prep.gain, fitter=fitter, saturated=saturated,
                               jump_threshold=jump_threshold or None,
                               refmask=prep.refmask, threads=options.threads,
                               resultant_noise=prep.resultant_noise)
        finally:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
    cards = list(prep.cards)
    cards.insert(2, ("JUMPTHR", float(jump_threshold or 0.0),
                     "[sigma] jump threshold, 0=off"))
    write_fit(output, result, header_cards=cards, overwrite=overwrite)
    return result
