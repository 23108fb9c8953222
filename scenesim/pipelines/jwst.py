"""JWST: uncal files the calibration pipeline accepts, the detector's reference files,
and Detector1 run offline on them.

Needs the optional ``jwst`` extra (``stdatamodels``, and ``jwst`` to run the pipeline);
imported only when used.

The uncal file (:func:`write_uncal`)
------------------------------------
Written through ``stdatamodels.jwst.datamodels.Level1bModel``, so it is what the data
models write (the ``ASDF`` extension included) and passes
``RampModel(path, strict_validation=True)``:

* ``SCI``: the exposure's resultants, uint16 DN, (nints, ngroups, ny, nx), unchanged;
* ``PIXELDQ`` (zeros) and ``GROUPDQ`` (zeros), as ``RampModel`` reads them;
* ``INT_TIMES``: start, middle and end of each integration (MJD UTC; BJD columns are
  the same numbers, no barycentric correction is made), from ``DATE-OBS`` and the
  frame clock: integration ``i`` starts at frame slot ``i * (1 + nreads)``
  (:func:`noise.clock.frame_slot`);
* the JWST keywords: ``INSTRUME``, ``DETECTOR`` (a JWST detector name), ``EXP_TYPE``,
  ``READPATT`` (the pattern, or ``ANY``), ``SUBARRAY`` (``FULL``, a JWST name, or
  ``GENERIC``) with ``SUBSTRT1/2``, ``SUBSIZE1/2``, ``FASTAXIS = 1`` and ``SLOWAXIS =
  2`` (the file is in scenesim's detector orientation: columns are the fast axis,
  rows the slow one; real NRS1 files, transposed into the DMS frame, differ),
  ``NINTS``, ``NGROUPS``, ``NFRAMES``, ``GROUPGAP``, ``DRPFRMS1`` (frames dropped after
  reset), ``FRMDIVSR`` (= ``NFRAMES``: scenesim averages, so the divisor is the frame
  count), ``TFRAME``, ``TGROUP``, ``EFFINTTM``, ``EFFEXPTM``, ``NOUTPUTS``,
  ``DATE-OBS``/``TIME-OBS`` and the exposure start/mid/end times;
* ``ZEROFRAME`` (uint16 DN, (nints, ny, nx)) and ``ZEROFRAM = T`` when a zero frame
  is given: the first read of each integration, for a NIRCam pattern with ``NFRAMES >
  1`` (:mod:`scenesim.pipelines.zeroframe`, which ``scenesim run --uncal`` calls);
  otherwise ``ZEROFRAM = F`` and no ``ZEROFRAME`` (with ``NFRAMES = 1`` the zero
  frame is group 1 itself; from an exposure file alone it cannot be rebuilt);
* scenesim's own cards (``GAIN``, ``RDNOISE``, the clock, the effects, the seed...) in
  the primary header, and the exposure's ``READS`` table, so the uncal is also a
  scenesim exposure (:func:`scenesim.io.exposure.read_exposure` reads it); the
  scenesim keywords whose name JWST uses for something else are left out (scenesim's
  ``DETECTOR`` is ``SSDETECT``, its pattern name ``SSREADPT``).

IRS2 (NIRSpec's interleaved reference sampling, detector preset ``NIRSPEC-IRS2``,
patterns ``NRSIRS2RAPID``/``NRSIRS2``): ``SCI`` holds every sample read, the exposure's
``SCI`` and ``RAWREF`` together in the raw layout of the jwst pipeline's IRS2 code
(:meth:`noise.clock.Detector.raw_columns`: the reference output's 640 columns, then
the four outputs' 512 normal and 128 interleaved columns each), turned into the DMS
orientation that code expects (``jwst.refpix.irs2_subtract_reference.correct_model``
swaps the axes back for ``NRS1``; for ``NRS2`` it also flips both): shape (nints,
ngroups, 3200, 2048) with ``FASTAXIS = 2``, ``SLOWAXIS = 1`` (NRS1; NRS2: ``-2``,
``-1``), ``SUBSIZE1 = SUBSIZE2 = 2048`` (the image's size: jwst's
``reffile_utils.ref_matches_sci`` accepts 3200 rows of data under ``SUBSIZE2 = 2048``,
so IRS2 references of either height match), ``NRS_NORM``/``NRS_REF`` from the
detector's interleave; ``PIXELDQ``/``GROUPDQ`` of that shape.  Only the full frame
(jwst's IRS2 code and NIRSpec read IRS2 only in full frame).  Such an uncal is not a
scenesim exposure: keep the exposure file for scenesim's own fits.

JWST describes only detectors it has: ``NOUTPUTS`` must be 1 or 4 and the array at
most 2048 x 2048, so an H4RG exposure (Roman) has no JWST uncal
(:mod:`scenesim.pipelines.roman` writes its Level 1 file).

Clock: the uncal records scenesim's own ``TFRAME`` and ``TGROUP``, so the pipeline
fits with the times the charge was simulated at.  Only a MULTIACCUM readout has an
uncal (:func:`check_uncal_readout`): an MA table or explicit read lists that are not
evenly spaced groups (ones that are, are recognised as MULTIACCUM) would be fitted
by jwst with the wrong times.  JWST's frame time (JDox,
"NIRCam Detector Subarrays") is ``((ncols/4 + 12) (nrows + 1) + 1) x 10 us`` with 4
outputs and ``(ncols + 12) (nrows + 2) x 10 us`` with 1: the ``H2RG`` preset
(``nroh = 12``, ``nfoh = 1``) is one pixel time (10 us, 1 ppm) short on full frames and
stripes, and a window matches exactly with ``nfoh = 2`` (:func:`jwst_frame_time`).

Reference files (:func:`write_reference_files`)
-----------------------------------------------
The references of :func:`scenesim.pipelines.reffiles.detector_reference` in the
formats the steps read as ``override_<type>``: ``gain`` (GainModel, e-/DN),
``readnoise`` (ReadnoiseModel: the CDS noise of two frames in DN, ``sqrt(2) * read_noise / gain``, as stcal expects:
:func:`scenesim.adapters.stcal.stcal_read_noise`), ``saturation`` (SaturationModel,
raw DN, bias included), ``superbias`` (SuperBiasModel, DN), ``linearity``
(LinearityModel, ``COEFFS`` (ncoeffs, ny, nx) on bias-subtracted DN), ``dark``
(DarkModel, DN per group in the exposure's own MULTIACCUM pattern, so the dark step
uses it without averaging frames: group ``g`` is the mean over its reads ``k`` of
``dark * (k + 1) * t_frame / gain``), ``mask`` (MaskModel, DQ), ``ipc`` (IPCModel:
JWST corrects IPC by *convolving* with this array, so it holds the inverse of the
engine's kernel, 5x5, :func:`scenesim.pipelines.reffiles.ipc_inverse_kernel`; the
superbias is the bias after that same convolution, since the ``ipc`` step runs before
``superbias``). Each is validated with ``strict_validation=True`` when it is written.

IRS2 (an interleaved detector, :func:`check_irs2_detector`): the references are for
Detector1 on the IRS2 uncal, so they are in its DMS orientation (:func:`irs2_to_dms`,
``FASTAXIS``/``SLOWAXIS`` as the uncal's), and the two that act before ``refpix``
strips the interleaved samples are in the raw IRS2 layout, 3200 x 2048 (jwst's
``dq_init`` ORs and ``superbias`` subtracts them as they are): ``mask`` (the image's
DQ on the normal samples, ``REFERENCE_PIXEL`` on the interleaved and
reference-output ones) and ``superbias`` (the image's bias on the normal samples,
:attr:`~scenesim.pipelines.reffiles.DetectorReference.raw_level` on the others).
``saturation`` stays 2048 x 2048: jwst's IRS2 saturation code
(``irs2_flag_saturation``) compares only the normal samples, and takes the bias of
its group-2 check from the IRS2 superbias.  ``refpix`` is the IRS2 file
(:func:`write_irs2_reference`); the others act after ``refpix``, on the 2048 x 2048
image; ``ipc`` (which jwst applies to the normal samples only) is the inverse kernel
turned into the DMS frame too.

Detector1 offline (:func:`run_detector1`)
----------------------------------------
CRDS is never contacted: the process gets an empty local CRDS cache
(``CRDS_PATH``), an unreachable server (``CRDS_SERVER_URL``), ``CRDS_MODE=local``, and
``STPIPE_DISABLE_CRDS_STEPPARS`` (no parameter references); the pipeline does not
prefetch references, and each step that needs one gets its ``override_<type>``.
An IRS2 uncal runs the same steps, ``refpix`` with its IRS2 algorithm and the
``refpix`` reference (the references must be the IRS2 ones of
:func:`write_reference_files`); the rate file is then in the DMS frame, which
:func:`scenesim.io.header.dms_to_detector` turns back for ``compare``.
Steps with no scenesim reference are skipped: ``persistence``, ``charge_migration``,
``picture_frame`` and ``clean_flicker_noise`` (also skipped by the pipeline's own
defaults), ``emicorr``, ``rscd``, ``firstframe``, ``lastframe`` and ``reset`` (MIRI
only).  ``ipc`` runs only when the exposure has IPC.  The rate file's header says what
ran (``S_IPC``, ``S_DARK``, ...), and :func:`scenesim.validate.compare.compare_files`
reads it.
"""

import contextlib
import math
import os
import tempfile

import numpy as np
from astropy.table import Table
from astropy.time import Time

from noise.clock import column_runs, copy_columns, detector_from_header, frame_slot
from noise.errors import FileFormatError, ParameterError
from noise.fitsio import atomic_path
from noise.validate import check_writable

from scenesim.adapters.stcal import stcal_read_noise
from scenesim.detector.dq import REFERENCE_PIXEL
from scenesim.io.exposure import Exposure
from scenesim.io.header import header_instrument, readout_from_table
from scenesim.outputs import check_not_dangling, made_directory
from scenesim.pipelines.instrument import resolve_instrument
from scenesim.pipelines.reffiles import check_reference_id, reference_id

__all__ = ["write_uncal", "uncal_model", "irs2_to_dms", "irs2_filter",
           "check_irs2_detector",
           "write_irs2_reference", "irs2_refpix_exposure", "write_reference_files", "run_detector1",
           "detector1_products", "jwst_frame_time", "check_subarray_name",
           "offline_crds", "uncal_identity", "REFERENCE_TYPES", "REQUIRED_TYPES",
           "DEFAULT_DATE_OBS", "SKIPPED_STEPS",
           "OFFLINE_CONTEXT"]

#: Observation start written when the scene gives none (ISO, UTC).
DEFAULT_DATE_OBS = "2026-01-01T00:00:00"

#: Reference types written by :func:`write_reference_files` (``ipc`` only with IPC);
#: an IRS2 detector also gets ``refpix`` (:func:`write_irs2_reference`).
REFERENCE_TYPES = ("gain", "readnoise", "saturation", "superbias", "linearity", "dark",
                   "mask", "ipc")

#: Reference types :func:`run_detector1` needs (an IRS2 uncal also ``refpix``).
REQUIRED_TYPES = ("gain", "readnoise", "saturation", "superbias", "linearity", "dark",
                  "mask")

#: Detector1 steps run without scenesim references (see the module notes).
SKIPPED_STEPS = ("persistence", "charge_migration", "picture_frame",
                 "clean_flicker_noise", "emicorr", "rscd", "firstframe", "lastframe",
                 "reset")

#: scenesim primary cards not copied into the uncal: JWST keywords of the same name
#: (set from the data model) or structural cards.
_JWST_OWNED = frozenset((
    "SIMPLE", "BITPIX", "NAXIS", "EXTEND", "DATE", "FILENAME", "DATAMODL", "TELESCOP",
    "ORIGIN", "FILETYPE", "NEXTEND", "DETECTOR", "SUBARRAY", "SUBSTRT1", "SUBSTRT2",
    "SUBSIZE1", "SUBSIZE2", "READPATT", "NINTS", "NGROUPS", "NFRAMES", "GROUPGAP",
    "TFRAME", "TGROUP", "NOUTPUTS", "EFFINTTM", "INSTRUME", "EXP_TYPE", "DATE-OBS",
    "TIME-OBS", "NRS_NORM", "NRS_REF"))


def _datamodels():
    try:
        from stdatamodels.jwst import datamodels
    except ImportError as exc:               # pragma: no cover - depends on the extra
        raise ParameterError(
            "JWST files need the optional 'jwst' extra (stdatamodels is not "
            "installed): pip install -e '.[jwst]'") from exc
    return datamodels


def check_subarray_name(name, detector=None, instrument=""):
    """Raise a one-line :class:`~noise.errors.ParameterError` unless ``name`` is a
    ``SUBARRAY`` value the JWST data models accept (``FULL``, ``GENERIC`` or a name
    of stdatamodels' ``subarray.schema.yaml``); the models would otherwise drop it
    with a warning and the file would fail strict validation.

    With the ``detector`` (:class:`noise.clock.Detector`) the name must also fit its
    readout: a full-frame name (``FULL``, ``FULLP``, ``FULL_...``) only for a full
    frame, any other name only for a window, and
    NIRCam's and NIRISS's square names (``SUB<N>`` and ``SUB<N>P``, e.g. ``SUB640``,
    ``SUB64P``) only for an N x N window (a 32 x 32 window said ``SUB640``)."""
    import re
    import warnings
    dm = _datamodels()
    model = dm.Level1bModel()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.meta.subarray.name = name
    if model.meta.subarray.name != name:
        raise ParameterError(
            f"[instrument] 'subarray' = {name!r} is not a JWST SUBARRAY name: use "
            f"'FULL', 'GENERIC' (any other window) or a name of the JWST subarray "
            f"lists (stdatamodels subarray.schema.yaml, e.g. 'SUB64P', 'SUB160')")
    if detector is None or name == "GENERIC":
        return name
    full = detector.subarray is None
    full_name = name.startswith("FULL")      # FULL, NIRCam's FULLP, FULL_SUPSTP...
    if full_name and not full:
        raise ParameterError(
            f"[instrument] 'subarray' = {name!r} is a full-frame name, but the readout "
            f"is a {detector.ny} x {detector.nx} window ([detector.subarray]); use "
            f"'GENERIC' or its JWST name")
    if not full_name and full:
        raise ParameterError(
            f"[instrument] 'subarray' = {name!r} names a subarray, but the readout is "
            f"the full {detector.ny} x {detector.nx} frame; use 'FULL' (or another "
            f"full-frame name such as 'FULLP')")
    square = re.fullmatch(r"SUB(\d+)P?", name)
    if square and str(instrument).upper() in ("NIRCAM", "NIRISS"):
        n = int(square.group(1))
        if (detector.ny, detector.nx) != (n, n):
            raise ParameterError(
                f"[instrument] 'subarray' = {name!r} is a {n} x {n} subarray, but the "
                f"window is {detector.ny} x {detector.nx}; use 'GENERIC' or the name of "
                f"a window of that size")
    return name


def jwst_frame_time(detector):
    """JWST's frame time (s) for ``detector``'s read-out size and outputs (JDox,
    "NIRCam Detector Subarrays"): ``((nx/4 + 12)(ny + 1) + 1) x 10 us`` with 4
    outputs, ``(nx + 12)(ny + 2) x 10 us`` with 1; NIRSpec IRS2: ``(712 (ny + 1) + 1)
    x 10 us`` = 14.58889 s (JWST planning tools' IRS2 frame; the clock of whole rows is
    one pixel time shorter)."""
    nx, ny, nout = detector.nx, detector.ny, detector.n_out_active
    if detector.interleave is not None and nout == 4:
        # IRS2: the same form with IRS2's row, (16 + 4 + 2) x 32 + 8 = 712 pixel
        # times: 14.58889 s in JWST planning tools (ours: 14.58888 s)
        return (detector.row_samples * (ny + 1) + 1) * 1e-5
    if nout == 4:
        return ((nx // 4 + 12) * (ny + 1) + 1) * 1e-5
    if nout == 1:
        return (nx + 12) * (ny + 2) * 1e-5
    raise ParameterError(f"JWST reads through 1 or 4 outputs, not {nout}")


def _check_jwst_detector(det):
    if det.n_out_active not in (1, 4) or det.naxis1 > 2048 or det.naxis2 > 2048:
        raise ParameterError(
            f"a JWST uncal needs a detector of at most 2048 x 2048 read through 1 or 4 "
            f"outputs (NOUTPUTS); {det.name!r} is {det.naxis2} x {det.naxis1} with "
            f"{det.n_out_active} outputs (an H4RG exposure: write a Roman L1 file, "
            f"scenesim.pipelines.roman)")


def check_irs2_detector(det, detector_name):
    """Raise unless ``det`` can be written in jwst's IRS2 layout (module notes)."""
    if det.interleave is None:
        return
    if not det.ref_output or det.subarray is not None or det.shape != (2048, 2048) \
            or det.n_out_active != 4 or det.raw_shape != (2048, 3200):
        raise ParameterError(
            f"a JWST IRS2 uncal needs the full 2048 x 2048 frame read through 4 outputs "
            f"with the reference output (raw 3200 x 2048, as preset 'NIRSPEC-IRS2'); "
            f"detector {det.name!r} reads {det.subarray_name} {det.ny} x {det.nx}, raw "
            f"{det.raw_shape[1]} x {det.raw_shape[0]}, reference output "
            f"{det.ref_output} (jwst's IRS2 code and NIRSpec read IRS2 only in full "
            f"frame)")
    if detector_name not in ("NRS1", "NRS2"):
        raise ParameterError(
            f"an IRS2 exposure is a NIRSpec one: [instrument] detector must be 'NRS1' "
            f"or 'NRS2', got {detector_name!r}")


def irs2_to_dms(raw, detector_name):
    """Raw IRS2 resultants (..., 2048, 3200) in scenesim's detector orientation to the
    DMS orientation of a NIRSpec uncal (..., 3200, 2048): the inverse of what
    ``jwst.refpix.irs2_subtract_reference.correct_model`` does (``NRS1``: transpose;
    ``NRS2``: transpose, then both axes reversed)."""
    dms = np.swapaxes(raw, -1, -2)
    if detector_name == "NRS2":
        dms = dms[..., ::-1, ::-1]
    return np.ascontiguousarray(dms)


def _as_exposure(exposure):
    if isinstance(exposure, Exposure):
        return exposure
    return Exposure.read(exposure)


def uncal_model(exposure, *, date_obs=None, zero_frame=None, reference_id=None):
    """The JWST ``Level1bModel`` of a scenesim exposure (module notes).

    Parameters
    ----------
    exposure : str, os.PathLike or scenesim.io.exposure.Exposure
    date_obs : str, keyword-only
        Start of the exposure, ISO UTC; default :data:`DEFAULT_DATE_OBS`.
    zero_frame : ndarray or None, keyword-only
        The first read of each integration, (nints, ny, nx) DN
        (:func:`scenesim.pipelines.zeroframe.zero_frames`); None: no ``ZEROFRAME``.
    reference_id : str or None, keyword-only
        Recorded as ``SSREFID`` (:func:`write_uncal`).

    Returns
    -------
    stdatamodels.jwst.datamodels.Level1bModel
    """
    dm = _datamodels()
    exp = _as_exposure(exposure)
    hdr = exp.header
    det = detector_from_header(hdr)
    _check_jwst_detector(det)
    ro = readout_from_table(hdr, exp.reads)
    check_uncal_readout(ro)
    t_frame = float(hdr["TFRAME"])
    ident = resolve_instrument(header_instrument(hdr), det, ro.name)
    check_subarray_name(ident["subarray"], det, ident["name"])
    irs2 = det.interleave is not None
    check_irs2_detector(det, ident["detector"])
    if irs2 and zero_frame is not None:
        raise ParameterError("'zero_frame': an IRS2 uncal has no ZEROFRAME (NIRSpec "
                             "patterns); pass None")
    start = Time(date_obs or DEFAULT_DATE_OBS, format="isot", scale="utc")
    day = 86400.0
    nints = ro.nints
    int_start = np.array([frame_slot(i, -1, ro.nreads) for i in range(nints)]) * t_frame
    int_end = int_start + (ro.nreads + 1) * t_frame
    if irs2:
        from scenesim.io.exposure import raw_resultants
        data = irs2_to_dms(raw_resultants(exp, det), ident["detector"])
    else:
        data = np.ascontiguousarray(exp.sci, dtype=np.uint16)
    m = dm.Level1bModel(data=data)
    meta = m.meta
    meta.telescope = "JWST"
    meta.filetype = "uncalibrated"
    meta.observation.date = start.isot[:10]
    meta.observation.time = start.isot[11:]
    meta.instrument.name = ident["name"]
    meta.instrument.detector = ident["detector"]
    ex = meta.exposure
    ex.type = ident["exp_type"]
    ex.readpatt = ident["readpatt"]
    ex.nints = nints
    ex.ngroups = ro.ngroups
    ex.nframes = int(ro.nframes)                 # MULTIACCUM: check_uncal_readout
    ex.groupgap = int(ro.groupgap)
    ex.drop_frames1 = int(ro.nskip)
    ex.frame_divisor = ex.nframes
    ex.nresets_at_start = 1
    ex.nresets_between_ints = 1
    ex.frame_time = t_frame
    ex.group_time = float(ro.tgroup(t_frame))
    ex.integration_time = ro.effective_integration_time(t_frame)
    # EFFEXPTM and XPOSURE are both the effective exposure time in the DMS
    # (integration time x integrations); DURATION is the whole span, resets included
    ex.effective_exposure_time = ex.integration_time * nints
    ex.exposure_time = ex.effective_exposure_time
    ex.duration = float(int_end[-1] - int_start[0])
    ex.zero_frame = zero_frame is not None
    if zero_frame is not None:
        zero_frame = np.asarray(zero_frame)
        if zero_frame.shape != (nints,) + det.shape:
            raise ParameterError(f"'zero_frame' must have the shape (nints, ny, nx) = "
                                 f"{(nints,) + det.shape}, got {zero_frame.shape}")
        m.zeroframe = np.ascontiguousarray(zero_frame, dtype=np.uint16)
    ex.noutputs = det.n_out_active
    ex.start_time = start.mjd
    ex.mid_time = start.mjd + ex.duration / 2 / day
    ex.end_time = start.mjd + ex.duration / day
    sub = meta.subarray
    sub.name = ident["subarray"]
    sub.xstart, sub.ystart = det.x0 + 1, det.y0 + 1
    sub.xsize, sub.ysize = det.nx, det.ny
    sub.fastaxis, sub.slowaxis = 1, 2
    if irs2:
        ex.nrs_normal = det.interleave.normal
        ex.nrs_reference = det.interleave.reference
        sub.fastaxis, sub.slowaxis = (2, 1) if ident["detector"] == "NRS1" else (-2, -1)
    mjd0 = start.mjd
    cols = [f"int_{when}_{scale}" for scale in ("MJD_UTC", "BJD_TDB")
            for when in ("start", "mid", "end")]
    times = np.zeros(nints, dtype=[("integration_number", ">i4")]
                     + [(c, ">f8") for c in cols])
    times["integration_number"] = np.arange(1, nints + 1)
    for col, t in (("start", int_start), ("mid", (int_start + int_end) / 2),
                   ("end", int_end)):
        times[f"int_{col}_MJD_UTC"] = mjd0 + t / day
        times[f"int_{col}_BJD_TDB"] = mjd0 + t / day
    m.int_times = times
    cards = [[k, v, hdr.comments[k]] for k, v in hdr.items()
             if k not in _JWST_OWNED and k not in ("COMMENT", "HISTORY", "")]
    cards += [["SSDETECT", det.name, "scenesim detector (preset) name"],
              ["SSREADPT", ro.name, "scenesim readout pattern name"]]
    if reference_id is not None:
        cards.append(["SSREFID", str(reference_id),
                      "scenesim id of this run's references"])
    reads = Table(exp.reads)
    reads_cards = [[str(k)[:8].upper(), v, ""] for k, v in reads.meta.items()
                   if isinstance(v, (bool, int, float, str))]
    ny, nx = data.shape[-2:]
    m.extra_fits = {
        "PRIMARY": {"header": cards},
        "PIXELDQ": {"data": np.zeros((ny, nx), dtype=np.uint32)},
        "GROUPDQ": {"data": np.zeros(data.shape, dtype=np.uint8)},
        "READS": {"data": reads.as_array(), "header": reads_cards},
    }
    return m


def check_uncal_readout(readout, what="the exposure"):
    """Refuse a readout a JWST uncal cannot describe: it records ``NFRAMES``-frame
    groups ``GROUPGAP`` apart, evenly spaced, which jwst's ramp fitting (stcal)
    assumes; an MA table or read lists written as such were fitted with the wrong
    times (a probe's ``[[0], [2], [3], [9]]``: -2.5 %, 18 sigma)."""
    if not readout.is_multiaccum:
        raise ParameterError(
            f"a JWST uncal describes MULTIACCUM groups (NFRAMES frames, GROUPGAP "
            f"apart, evenly spaced), which jwst's ramp fitting assumes; {what}'s "
            f"readout {readout.name!r} is an MA table or read lists that are not such "
            f"groups, which jwst would fit with the wrong times: use the 'pattern' or "
            f"'nframes' form, or --l1 for a Roman L1 file")


def write_uncal(exposure, path, *, date_obs=None, zero_frame=None, overwrite=False,
                reference_id=None):
    """Write the JWST uncal file of a scenesim exposure (module notes).

    Parameters
    ----------
    exposure : str, os.PathLike or scenesim.io.exposure.Exposure
    path : str or os.PathLike
        Output ``.fits`` file, written atomically.
    date_obs : str, keyword-only
        Exposure start, ISO UTC (default :data:`DEFAULT_DATE_OBS`).
    zero_frame : ndarray or None, keyword-only
        ``ZEROFRAME`` data (:func:`uncal_model`).
    overwrite : bool, keyword-only
    reference_id : str or None, keyword-only
        :func:`scenesim.pipelines.reffiles.reference_id` of the run's references,
        recorded as ``SSREFID`` (:func:`run_detector1` refuses references with
        another).

    Returns
    -------
    str
        ``path``.
    """
    path = check_writable("uncal path", path, overwrite=overwrite)
    model = uncal_model(exposure, date_obs=date_obs, zero_frame=zero_frame,
                        reference_id=reference_id)
    _save_fits(model, path, overwrite)
    return path


def _save_fits(model, path, overwrite):
    """Write a data model to ``path`` atomically (its FILENAME is ``path``'s name)."""
    model.meta.filename = os.path.basename(os.fspath(path))
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
        model.to_fits(f)
        model.meta.filename = os.path.basename(os.fspath(path))
    model.close()


# ------------------------------------------------------------------ reference files
def _ref_meta(model, reftype, ident, det, description):
    axes = (1, 2)
    if det.interleave is not None:          # IRS2: the uncal's DMS frame
        axes = (2, 1) if ident["detector"] == "NRS1" else (-2, -1)
    meta = model.meta
    meta.reftype = reftype.upper()
    meta.description = description
    meta.author = "scenesim"
    meta.pedigree = "DUMMY"
    meta.useafter = "2000-01-01T00:00:00"
    meta.telescope = "JWST"
    meta.instrument.name = ident["name"]
    meta.instrument.detector = ident["detector"]
    try:                                  # not every reference schema has these
        meta.subarray.name = ident["subarray"]
        meta.subarray.xstart, meta.subarray.ystart = det.x0 + 1, det.y0 + 1
        meta.subarray.xsize, meta.subarray.ysize = det.nx, det.ny
        meta.subarray.fastaxis, meta.subarray.slowaxis = axes
    except AttributeError:
        pass
    try:
        meta.exposure.type = ident["exp_type"]
        meta.exposure.readpatt = "ANY"
    except AttributeError:
        pass


def write_reference_files(reference, readout, t_frame, directory, *, instrument=None,
                          overwrite=False):
    """Write the JWST reference files of a simulated detector (module notes).

    Parameters
    ----------
    reference : scenesim.pipelines.reffiles.DetectorReference
    readout : scenesim.detector.readout.Readout
        The exposure's readout (MULTIACCUM: the dark is written in its pattern).
    t_frame : float
        Frame time, s.
    directory : str or os.PathLike
        Created if missing; files ``jwst_<type>.fits``.
    instrument : scenesim.pipelines.instrument.InstrumentConfig or None, keyword-only
    overwrite : bool, keyword-only

    Returns
    -------
    dict
        ``{reftype: path}`` (``ipc`` only when the detector has IPC).
    """
    dm = _datamodels()
    det = reference.detector
    _check_jwst_detector(det)
    if not readout.is_multiaccum:
        raise ParameterError(
            f"the dark reference is written in the exposure's MULTIACCUM pattern; "
            f"readout {readout.name!r} is not one")
    ident = resolve_instrument(instrument, det, readout.name)
    types = [t for t in REFERENCE_TYPES if t != "ipc" or reference.has_ipc]
    if det.interleave is not None:
        types.append("refpix")
    paths = {t: os.path.join(os.fspath(directory), f"jwst_{t}.fits") for t in types}
    os.makedirs(directory, exist_ok=True)
    for t, path in paths.items():
        check_writable(f"{t} reference", path, overwrite=overwrite)
    g = reference.gain
    shape = det.shape
    f32 = np.float32
    dq0 = np.zeros(shape, dtype=np.uint32)
    nc = reference.linearity.size
    if det.interleave is not None:          # IRS2: DMS frame, raw layout before refpix
        check_irs2_detector(det, ident["detector"])

        def img(a):
            return irs2_to_dms(a, ident["detector"])

        def raw(a, fill):
            return irs2_to_dms(_raw_layout(det, a, fill), ident["detector"])
    else:
        def img(a):
            return a

        def raw(a, fill):
            return a
    raw_shape = raw(dq0, 0).shape
    makers = {
        "gain": lambda: (dm.GainModel(data=np.full(shape, g, dtype=f32)),
                         "gain (e-/DN) of the simulated ADC"),
        "readnoise": lambda: (dm.ReadnoiseModel(data=img(np.asarray(
            stcal_read_noise(reference.read_noise, g), dtype=f32))),
            "white read noise: CDS of two frames, DN"),
        "saturation": lambda: (dm.SaturationModel(
            data=img((reference.saturation / g).astype(f32)), dq=dq0.copy()),
            "full-well level, raw DN with bias"),
        "superbias": lambda: (dm.SuperBiasModel(
            data=raw(_superbias(reference) / g, reference.raw_level / g).astype(f32),
            err=np.zeros(raw_shape, dtype=f32),
            dq=np.zeros(raw_shape, dtype=np.uint32)), "mean reset level (bias), DN"),
        "linearity": lambda: (dm.LinearityModel(
            coeffs=np.broadcast_to(reference.linearity.astype(f32)[:, None, None],
                                   (nc,) + shape).copy(), dq=dq0.copy()),
            "inverse of the simulated nonlinearity"),
        "dark": lambda: (_dark_model(dm, reference, readout, t_frame, img),
                         "dark current and hot pixels, DN per group"),
        "mask": lambda: (dm.MaskModel(dq=raw(reference.mask.astype(np.uint32),
                                              REFERENCE_PIXEL).astype(np.uint32)),
                         "reference and hot pixels"),
        "ipc": lambda: (dm.IPCModel(data=img(reference.ipc_inverse.astype(f32))),
                        "IPC correction: inverse kernel, convolved"),
    }
    for t in types:
        if t == "refpix":
            write_irs2_reference(det, paths[t], instrument=instrument,
                                 readout_name=readout.name, overwrite=overwrite)
            continue
        model, description = makers[t]()
        model.extra_fits = {"PRIMARY": {"header": [
            ["SSREFID", reference_id(reference), "scenesim id of these references"]]}}
        _save_ref(model, t, ident, det, description, paths[t], overwrite)
    return paths


def irs2_filter(detector):
    """The IRS2 reference file's ``beta`` (one complex value per frequency of a frame's
    time line, ``ny * row_samples`` samples; the same for the four outputs): a
    low-pass that turns the reference samples jwst's IRS2 code places on the time line
    (``2 * reference`` slots around each excursion, zero elsewhere) into their local
    mean at every normal pixel.  Unit in-band gain for that placement: ``row_samples /
    (2 * reference * n_excursions)`` (712 / 256 for NIRSpec) times a response of 1 up
    to half the cut-off, a cosine taper to 0 at ``1 / (2 period)`` cycles per sample
    (the first alias of the excursion comb, ``period = normal + reference + 2 jump``).
    No fitted weights: not the optimal coefficients of Rauscher et al. (2017)."""
    il = detector.interleave
    n = detector.ny * detector.row_samples
    f = np.abs(np.fft.fftfreq(n))                   # cycles per sample
    f2 = 1.0 / (2 * il.period)
    f1 = f2 / 2
    h = np.where(f <= f1, 1.0, np.where(f >= f2, 0.0,
                                        0.5 * (1 + np.cos(np.pi * (f - f1) / (f2 - f1)))))
    gain = detector.row_samples / (2 * il.reference * detector.n_excursions)
    return (gain * h).astype(np.complex64)


def write_irs2_reference(detector, path, *, instrument=None, readout_name="NRSIRS2RAPID",
                         overwrite=False):
    """Write the ``refpix`` reference file jwst's IRS2 step needs (``IRS2Model``), for
    a simulated detector: ``beta`` = :func:`irs2_filter` for every output, ``alpha`` =
    0 (the reference output is not used), and a ``DQ`` table of 8 rows (outputs 1-4,
    odd/even) flagging no interleaved reference pixel as bad.  Only jwst's IRS2
    geometry (preset ``NIRSPEC-IRS2``: 712 x 2048 samples per frame) is accepted,
    since the jwst code requires ``2 * 712 * 2048`` rows."""
    dm = _datamodels()
    det = detector
    ident = resolve_instrument(instrument, det, readout_name)
    check_irs2_detector(det, ident["detector"])
    if det.interleave is None or det.row_samples * det.ny != 712 * 2048:
        raise ParameterError(
            f"an IRS2 reference file is for the jwst IRS2 geometry (712 x 2048 samples "
            f"per frame, preset 'NIRSPEC-IRS2'); detector {det.name!r} has "
            f"interleave {det.interleave} and {det.row_samples} x {det.ny}")
    path = check_writable("refpix reference", path, overwrite=overwrite)
    beta = irs2_filter(det)
    as_float = np.empty(2 * beta.size, dtype=np.float32)
    as_float[0::2], as_float[1::2] = beta.real, beta.imag
    zeros = np.zeros_like(as_float)
    table = np.zeros(as_float.size, dtype=[(f"{w}_{k}", ">f4") for w in ("alpha", "beta")
                                           for k in range(4)])
    for k in range(4):
        table[f"alpha_{k}"] = zeros
        table[f"beta_{k}"] = as_float
    dq = np.zeros(8, dtype=[("OUTPUT", ">u2"), ("ODD_EVEN", ">u2"), ("MASK", ">u4")])
    dq["OUTPUT"] = np.repeat(np.arange(1, 5), 2)
    dq["ODD_EVEN"] = np.tile([1, 2], 4)
    model = dm.IRS2Model(irs2_table=table, dq_table=dq)
    _save_ref(model, "refpix", ident, det, "IRS2: low-pass of the interleaved "
              "reference samples, no reference output", path, overwrite)
    return path


def _ipc_convolve(image, kernel, refmask):
    """What JWST's ``ipc`` step does to one frame (``jwst.ipc.ipc_corr.ipc_convolve``):
    the science region (inside the reference border) is convolved with ``kernel``,
    zero outside it; reference pixels are left as they are."""
    from scipy.ndimage import convolve
    rows = np.flatnonzero(~refmask.all(axis=1))
    cols = np.flatnonzero(~refmask.all(axis=0))
    out = np.array(image, dtype=np.float64)
    if rows.size and cols.size:
        y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        out[y0:y1, x0:x1] = convolve(out[y0:y1, x0:x1], kernel, mode="constant",
                                     cval=0.0)
    return out


def _superbias(reference):
    """The bias as the superbias step meets it: after the ``ipc`` step when the
    detector has IPC (that step runs first and convolves the bias too)."""
    if not reference.has_ipc:
        return reference.bias
    return _ipc_convolve(reference.bias, reference.ipc_inverse,
                         reference.detector.reference_mask())


def _raw_layout(det, image, fill):
    """``image`` (ny, nx) in the raw layout of ``det`` (:meth:`noise.clock.Detector.
    raw_columns`), (ny, raw_nx): each normal sample its pixel's value, every other
    (interleaved reference, reference output) ``fill``."""
    _, _, image_x = det.raw_columns()
    out = np.full((image.shape[0], image_x.size), fill, dtype=np.asarray(image).dtype)
    normal = np.flatnonzero(image_x >= 0)
    return copy_columns(out, image, column_runs(normal, image_x[normal]))


def _dark_model(dm, reference, readout, t_frame, orient=lambda a: a):
    """DarkModel in the exposure's MULTIACCUM pattern: group ``g`` is the mean over
    its reads ``k`` of ``dark * (k + 1) * t_frame / gain`` (DN); ``orient`` turns an
    image into the file's frame (IRS2: :func:`irs2_to_dms`)."""
    mean_k = np.array([np.mean(np.asarray(r, dtype=np.float64) + 1.0)
                       for r in readout.resultants])
    cube = (mean_k[:, None, None] * (float(t_frame) / reference.gain)) \
        * reference.dark[None, :, :]
    model = dm.DarkModel(data=orient(cube.astype(np.float32)),
                         err=np.zeros(cube.shape, dtype=np.float32),
                         dq=np.zeros(reference.detector.shape, dtype=np.uint32))
    model.meta.exposure.nframes = int(readout.nframes)
    model.meta.exposure.groupgap = int(readout.groupgap)
    model.meta.exposure.ngroups = int(readout.ngroups)
    model.meta.exposure.nints = 1
    return model


def _save_ref(model, reftype, ident, det, description, path, overwrite):
    _ref_meta(model, reftype, ident, det, description)
    model.validate()
    _save_fits(model, path, overwrite)
    # read back with strict validation: the file is what the step will open
    dm = _datamodels()
    with dm.open(path, strict_validation=True):
        pass


# ------------------------------------------------------------------ the pipeline
#: The CRDS context recorded in the pipeline's outputs (``CRDS_CTX``): none was used.
OFFLINE_CONTEXT = "N/A"


@contextlib.contextmanager
def offline_crds():
    """Environment in which stpipe and CRDS never reach the network (module notes);
    the previous values are restored afterwards.

    Besides the environment, stpipe's ``crds_client.get_context_used`` (which asks
    the CRDS server which context *would* apply, only to record it in the output
    header) answers :data:`OFFLINE_CONTEXT` while inside: no context was used, since
    every reference is an override.
    """
    from stpipe import crds_client
    keys = ("CRDS_PATH", "CRDS_SERVER_URL", "CRDS_MODE", "STPIPE_DISABLE_CRDS_STEPPARS")
    saved = {k: os.environ.get(k) for k in keys}
    saved_context = crds_client.get_context_used
    with tempfile.TemporaryDirectory(prefix="scenesim-crds-") as cache:
        os.environ.update({"CRDS_PATH": cache,
                           "CRDS_SERVER_URL": "https://crds.invalid",
                           "CRDS_MODE": "local", "STPIPE_DISABLE_CRDS_STEPPARS": "True"})
        crds_client.get_context_used = lambda observatory: OFFLINE_CONTEXT
        try:
            yield cache
        finally:
            crds_client.get_context_used = saved_context
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v


def irs2_refpix_exposure(uncal, refpix_reference, exposure, **step_pars):
    """jwst's ``refpix`` step (its IRS2 algorithm) run offline on an IRS2 uncal, as a
    scenesim :class:`~scenesim.io.exposure.Exposure` that scenesim's fitters take
    (``scenesim.calib.prepare.fit_exposure_file(..., options=PrepareOptions(refpix=
    'none'))``) and ``scenesim compare`` grades.

    Only this step of Detector1 runs (:func:`run_detector1` runs all of them): its
    corrected ramp, 2048 x 2048, for scenesim's own fitters.  ``PIXELDQ``/``GROUPDQ`` start at 0 (scenesim's fit flags saturation from
    the data).

    Parameters
    ----------
    uncal : str
        An IRS2 uncal (:func:`write_uncal` of an IRS2 exposure).
    refpix_reference : str
        The step's ``refpix`` reference (:func:`write_irs2_reference`).
    exposure : str or Exposure
        The scenesim exposure the uncal was written from (header, ``READS``).
    **step_pars
        ``RefPixStep`` parameters (e.g. ``ovr_corr_mitigation_ftr``).

    Returns
    -------
    Exposure
        ``sci``: the corrected ramp, float32 DN, (nints, ngroups, ny, nx), back in
        scenesim's detector orientation; ``name``: ``'<uncal> (jwst refpix IRS2)'``.
    """
    dm = _datamodels()
    exp = _as_exposure(exposure)
    det = detector_from_header(exp.header)
    with dm.open(os.fspath(uncal)) as m:
        name = m.meta.instrument.detector
        if det.interleave is None or m.meta.exposure.nrs_normal is None:
            raise ParameterError(
                f"'uncal' {os.fspath(uncal)!r} is not an IRS2 uncal (no NRS_NORM), or "
                f"exposure {exp.name!r} is not an IRS2 exposure")
    with offline_crds():
        from jwst.refpix import RefPixStep
        result = RefPixStep.call(os.fspath(uncal), override_refpix=os.fspath(
            refpix_reference), **step_pars)
        try:
            if result.meta.cal_step.refpix != "COMPLETE":
                raise FileFormatError(
                    f"jwst's refpix step did not complete on {os.fspath(uncal)!r} "
                    f"({result.meta.cal_step.refpix})")
            data = np.asarray(result.data, dtype=np.float32)
        finally:
            result.close()
    # back from DMS: the inverse of irs2_to_dms on the 2048 x 2048 image
    if name == "NRS2":
        data = data[..., ::-1, ::-1]
    sci = np.ascontiguousarray(np.swapaxes(data, -1, -2))
    if sci.shape != exp.sci.shape:
        raise FileFormatError(f"jwst's refpix step returned shape {sci.shape}, not the "
                              f"exposure's {exp.sci.shape}")
    return Exposure(sci, exp.header, exp.reads, f"{os.fspath(uncal)} (jwst refpix IRS2)")


#: The image extension of each reference type whose size must be the uncal's.
_REFERENCE_IMAGE = {"gain": "SCI", "readnoise": "SCI", "saturation": "SCI",
                    "superbias": "SCI", "linearity": "COEFFS", "dark": "SCI",
                    "mask": "DQ"}


def _check_references_match(uncal, references, irs2):
    """Raise unless every reference is of the uncal's detector and size and, where
    the uncal records scenesim's gain (``GAIN``), the gain reference holds it (a set
    written for another array broke inside jwst; another detector's set of the same
    size ran without a word, gain 2.0 on a 1.8 e-/DN exposure).  A full-frame
    reference (``SUBARRAY = 'FULL'``) fits any subarray (jwst cuts it); IRS2 uncals
    have their own size rules (:func:`_check_irs2_references`)."""
    from astropy.io import fits
    with fits.open(os.fspath(uncal)) as hdul:
        h0 = hdul[0].header
        detector, gain = h0.get("DETECTOR"), h0.get("GAIN")
        run_id = h0.get("SSREFID")
        shape = (hdul["SCI"].header.get("NAXIS2"), hdul["SCI"].header.get("NAXIS1"))
    for reftype, ext in _REFERENCE_IMAGE.items():
        if reftype not in references:
            continue
        ref = os.fspath(references[reftype])
        try:
            with fits.open(ref) as hdul:
                theirs = hdul[0].header.get("DETECTOR")
                full = str(hdul[0].header.get("SUBARRAY", "")).upper() == "FULL"
                h = hdul[ext].header
                ref_shape = (h.get("NAXIS2"), h.get("NAXIS1"))
                median = (float(np.median(hdul[ext].data))
                          if reftype == "gain" and gain is not None else None)
                their_id = hdul[0].header.get("SSREFID")
        except (OSError, KeyError, TypeError, ValueError) as exc:
            raise FileFormatError(f"{reftype} reference {ref!r} is not a JWST reference "
                                  f"file with a {ext!r} image ({exc})") from exc
        if detector and theirs and theirs not in ("ANY", "MULTIPLE") and \
                theirs != detector:
            raise ParameterError(f"{reftype} reference {ref!r} is for detector "
                                 f"{theirs!r}, the uncal {os.fspath(uncal)!r} for "
                                 f"{detector!r}")
        if not irs2 and ref_shape != shape and not full:   # jwst cuts a FULL one
            raise ParameterError(
                f"{reftype} reference {ref!r} is {ref_shape[0]} x {ref_shape[1]} pixels, "
                f"the uncal {os.fspath(uncal)!r} {shape[0]} x {shape[1]}: references of "
                f"another array (write them with 'scenesim run SCENE --reffiles')")
        if median is not None and not math.isclose(median, float(gain), rel_tol=1e-4):
            raise ParameterError(
                f"gain reference {ref!r} holds {median:g} e-/DN, but the uncal "
                f"{os.fspath(uncal)!r} was digitised at GAIN = {gain:g} e-/DN: "
                f"references of another run")
        check_reference_id(reftype, ref, their_id, "uncal", uncal, run_id)


def _check_irs2_references(uncal, references):
    """Raise unless ``references`` are the IRS2 ones (module notes): a ``refpix``
    reference and a 3200 x 2048 (raw IRS2 layout) mask and superbias."""
    from astropy.io import fits
    if "refpix" not in references:
        raise ParameterError(
            f"'uncal' {os.fspath(uncal)!r} is an IRS2 uncal: 'references' needs the IRS2 "
            f"'refpix' reference (write_reference_files of the IRS2 detector writes it)")
    for t, ext in (("mask", "DQ"), ("superbias", "SCI")):
        h = fits.getheader(os.fspath(references[t]), ext)
        shape = (h.get("NAXIS2"), h.get("NAXIS1"))
        if shape != (3200, 2048):
            raise ParameterError(
                f"'uncal' {os.fspath(uncal)!r} is an IRS2 uncal: its {t} reference "
                f"{os.fspath(references[t])!r} must be in the raw IRS2 layout (3200 x "
                f"2048, DMS), got {shape[0]} x {shape[1]} (write_reference_files of the "
                f"IRS2 detector writes it)")


def detector1_products(uncal, output_dir, *, ramp=False):
    """``{'rate': path, 'rateints': path}`` (and ``'ramp'``) that Detector1 writes for
    ``uncal`` in ``output_dir``: the stem as the pipeline makes it, the input's name
    without its extension and without the one pipeline suffix it may end in
    (``x_uncal`` -> ``x``, but also ``x_rate`` -> ``x``: jwst's ``remove_suffix``)."""
    stem = os.path.basename(os.fspath(uncal))
    if stem.lower().endswith(".fits"):
        stem = stem[:-len(".fits")]
    try:
        from jwst.lib.suffix import remove_suffix
        stem = remove_suffix(stem)[0]
    except ImportError:                    # (the pipeline is not installed: its name)
        if stem.endswith("_uncal"):
            stem = stem[:-len("_uncal")]
    kinds = ("rate", "rateints") + (("ramp",) if ramp else ())
    return {kind: os.path.join(os.fspath(output_dir), f"{stem}_{kind}.fits")
            for kind in kinds}


def check_uncal_file(path):
    """Raise unless ``path`` is an existing JWST level-1b (uncal) FITS file."""
    from noise.fitsio import open_fits
    from noise.validate import check_existing_file
    path = check_existing_file("uncal", path)
    with open_fits(path, "uncal") as hdul:
        model = hdul[0].header.get("DATAMODL")
        names = {h.name for h in hdul}
    if model != "Level1bModel" or not {"SCI", "ASDF"} <= names:
        raise FileFormatError(
            f"uncal {path!r} is not a JWST level-1b (uncal) file: DATAMODL = {model!r}"
            f" (expected 'Level1bModel'), extensions {sorted(names)}; write one with "
            f"'scenesim run SCENE --uncal'")
    return path


def uncal_identity(path):
    """``(header, (ny, nx))`` of an uncal file (:func:`check_uncal_file`): its primary
    header, which the rate file inherits (``NINTS``, ``NGROUPS``, ``READPATT``/
    ``SSREADPT``, ``TFRAME``, scenesim's ``GAIN``, ``SEED``, ``SCENEID``...), and the
    image's shape (``SUBSIZE2`` x ``SUBSIZE1``: the detector's window, also for an IRS2
    uncal, whose ``SCI`` holds the raw layout)."""
    from astropy.io import fits
    hdr = fits.getheader(os.fspath(path))
    try:
        shape = (int(hdr["SUBSIZE2"]), int(hdr["SUBSIZE1"]))
    except (KeyError, TypeError, ValueError):
        sci = fits.getheader(os.fspath(path), "SCI")
        shape = (sci.get("NAXIS2"), sci.get("NAXIS1"))
    return hdr, shape


def run_detector1(uncal, references, output_dir, *, save_calibrated_ramp=False,
                  steps=None, overwrite=False, inputs=()):
    """Run ``calwebb_detector1`` on ``uncal`` offline with scenesim's references.

    Parameters
    ----------
    uncal : str
        A JWST uncal file (:func:`write_uncal`).
    references : dict
        ``{reftype: path}`` (:func:`write_reference_files`); a step whose reference is
        missing is skipped (``ipc`` without IPC).
    output_dir : str
        Where the pipeline writes ``<stem>_rate.fits`` and ``<stem>_rateints.fits``.
    save_calibrated_ramp : bool, keyword-only
        Also keep the calibrated ramp (``<stem>_ramp.fits``).
    steps : dict or None, keyword-only
        Extra step parameters, merged over scenesim's (e.g.
        ``{"jump": {"rejection_threshold": 5}}``).
    overwrite : bool, keyword-only
        Replace existing rate files (default: refuse them, before running).
    inputs : sequence of str, keyword-only
        Other files the caller reads (a truth, an exposure): like the uncal and the
        references, never replaced by a product, even with ``overwrite``.

    Returns
    -------
    dict
        ``rate`` and ``rateints`` paths (``rateints`` None when not written).
    """
    from astropy.io import fits
    from scenesim.outputs import check_outputs
    uncal = check_uncal_file(uncal)
    irs2 = "NRS_NORM" in fits.getheader(os.fspath(uncal))
    products = detector1_products(uncal, output_dir, ramp=save_calibrated_ramp)
    output_dir = check_not_dangling("output_dir", os.fspath(output_dir))
    if os.path.isdir(output_dir):
        # never the uncal nor a reference, even with overwrite (an input named
        # x_rate.fits has the product x_rate.fits); an existing product only with it
        check_outputs({f"Detector1 {k} file": p for k, p in products.items()},
                      inputs=[uncal, *map(os.fspath, references.values()),
                              *map(os.fspath, inputs)], overwrite=overwrite)
    elif os.path.exists(output_dir):
        raise ParameterError(f"the Detector1 output directory {output_dir!r} is a file")
    elif not os.path.isdir(os.path.dirname(os.path.abspath(output_dir))):
        raise ParameterError(f"the Detector1 output directory {output_dir!r}: its parent "
                             f"directory does not exist")
    missing = [t for t in REQUIRED_TYPES if t not in references]
    if missing:
        raise ParameterError(f"'references' lacks {missing}; write them with "
                             f"write_reference_files")
    if irs2:
        _check_irs2_references(uncal, references)
    _check_references_match(uncal, references, irs2)
    cfg = {name: {"skip": True} for name in SKIPPED_STEPS}
    for step, reftypes in (("dq_init", ("mask",)),
                           ("saturation", ("saturation", "superbias")),
                           ("superbias", ("superbias",)), ("linearity", ("linearity",)),
                           ("dark_current", ("dark",)), ("jump", ("gain", "readnoise")),
                           ("ramp_fit", ("gain", "readnoise")), ("gain_scale", ("gain",)),
                           ("ipc", ("ipc",))):
        if all(t in references for t in reftypes):
            cfg[step] = {f"override_{t}": os.fspath(references[t]) for t in reftypes}
        else:
            cfg[step] = {"skip": True}
    if "refpix" in references:            # IRS2: the step's reference file
        cfg["refpix"] = {"override_refpix": os.fspath(references["refpix"])}
    for name, pars in (steps or {}).items():
        cfg.setdefault(name, {}).update(pars)
    with made_directory(output_dir), offline_crds():   # (removed again if it fails)
        from jwst.pipeline import Detector1Pipeline
        pipe = Detector1Pipeline(steps=cfg)
        pipe.prefetch_references = False
        pipe.output_dir = output_dir
        pipe.save_results = True
        pipe.save_calibrated_ramp = save_calibrated_ramp
        result = pipe.run(os.fspath(uncal))
        result.close()
    rate, rateints = products["rate"], products["rateints"]
    if not os.path.exists(rate):
        raise FileFormatError(f"Detector1 wrote no rate file {rate!r}")
    return {"rate": rate, "rateints": rateints if os.path.exists(rateints) else None}
