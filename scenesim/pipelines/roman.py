"""Roman: Level 1 ASDF files, the detector's references, and romancal's ramp fit offline.

Needs the optional ``roman`` extra (``roman_datamodels``, ``romancal``); imported only
when used.

The L1 file (:func:`write_l1`)
------------------------------
A ``roman_datamodels`` ``ScienceRawModel`` (``WfiScienceRaw``), made with the models'
own ``create_fake_data`` (every required field present) and then filled:

* ``data``: the exposure's resultants, uint16 DN, (nresultants, ny, nx) (Roman has
  one integration per exposure: a multi-integration exposure is refused);
* ``meta.exposure.read_pattern``: the reads of each resultant, counted from 1 as
  romancal counts them (read ``k`` at ``k * frame_time`` after the reset): scenesim's
  0-based read ``k`` (at ``(k + 1) t_frame``, rolling reset) is romancal's ``k + 1``,
  so the resultant times agree exactly; ``frame_time`` = scenesim's ``TFRAME``;
  ``nresultants``, ``ma_table_name`` (the pattern name), ``exposure_time`` and
  ``effective_exposure_time``;
* ``amp33``: the reference output (below), uint16 DN, (nresultants, ny, 128);
* ``meta.scenesim_cards``: the exposure's ``SEED``, ``SEEDENT``, ``SCENEID`` and
  ``GAIN`` as its header has them, so that ``scenesim pipeline roman --truth`` refuses the truth
  of another exposure before romancal runs (:func:`l1_identity`); and, with the
  run's references, ``meta.scenesim_refid``.

The amp33 reference channel
---------------------------
What public documents say of it: the WFI's H4RG-10s are read through 32 science
outputs of 128 columns each plus a 33rd output that reads no pixel, clocked in step
with the others, so it records the electronics' noise without any charge (romancal's
``refpix`` step uses it, with the reference pixels, against correlated read noise;
the ``rad`` schema ``wfi_science_raw`` gives ``amp33`` the shape of one output,
(n_resultants, 4096, 128)).  What its columns mean is romancal's ``refpix`` code's
(``romancal.refpix._data``): amp33 is stacked to the right of the 32 science channels
as a 33rd channel of 128 columns; the odd channels are flipped to bring them into
reading order and the even ones (0, 2, ..., and amp33, number 32) are not, so amp33's
column ``c`` is the ``c``-th sample of its row in time, read at the instant output
0's column ``c`` is (scenesim's even outputs scan left to right too,
:meth:`noise.clock.Detector.output_reversed`), and rows follow in time as the image's.

scenesim's detector model has such an output: ``ref_output = true``
(:class:`noise.clock.Detector`; ``scenes/roman_wfi.toml`` sets it on the WFI preset,
which leaves it off because a one-output ``window``, which the loop tests use, cannot
have one).  Its samples are the exposure's ``RAWREF`` extension, averaged into the
resultants and digitised as the pixels are; on a detector without interleave every
``RAWREF`` column is the reference output's, mirrored with respect to output 0
(:meth:`noise.clock.Detector.raw_columns`), so amp33 is ``RAWREF`` with its columns
put in time order (slot ``c`` in column ``c``).  Each sample carries what the
generator gives the reference output (:mod:`noise.generator`): the correlated 1/f at
its instant (the one series every output shares), the frame's pedestal, the bias
offset, white noise of ``mean(rd_noise) * ref_ratio``, and its own uncorrelated 1/f
and ACN; no charge, no kTC.  So amp33 minus a science output's pixels read at the same
instants holds no correlated 1/f and no pedestal, only white noise of variance
``rd^2 (1 + ref_ratio^2)`` per read, plus what no output shares: each output's own
1/f and ACN, and the pixels' kTC and fixed bias pattern, constant through the ramp
(``tests/pipelines/test_roman_amp33.py`` checks that variance under a correlated 1/f
that alone makes the pixels 9-14 times noisier than white).  A reference output that
does not fit amp33 (not 128 samples per row, or interleaved samples: an IRS2
detector) is refused, by ``scenesim run --l1`` before the run.

Without a reference output (``ref_output`` false: the WFI and H4RG presets as they
stand, e.g. the loop tests' windows), amp33 is a fallback that only gives the
file its complete layout: no charge, the bias offset (``BIASOFF``), the per-frame
pedestal (``PEDESTAL``, drawn anew, not the one the pixels saw) and white noise at
the reference-pixel level (``RDNOISE * REFRATIO``), each read drawn independently
(from the exposure seed's stream ``(33,)``), averaged over the resultant's reads and
digitised like the pixels.  It holds none of the correlated 1/f, so romancal's
``refpix`` must not be run on such files.

References (:func:`write_reference_files`)
------------------------------------------
From :func:`scenesim.pipelines.reffiles.detector_reference`, in the units romancal
reads them in:

* ``roman_gain.asdf`` (``GainRefModel``, e-/DN);
* ``roman_readnoise.asdf`` (``ReadnoiseRefModel``: DN **per read**, which is what
  romancal's ramp fitting multiplies by the gain and hands to stcal's
  Casertano/likelihood fitters);
* ``roman_mask.asdf`` (``MaskRefModel``: reference and hot pixels, the JWST/Roman DQ
  bits);
* ``roman_saturation.asdf`` (``SaturationRefModel``: raw DN with the bias, the level of
  ``detector_reference``; the ADC's top code when the scene sets no full well);
* when the detector is nonlinear, ``roman_linearity.asdf`` (``LinearityRefModel``) and
  ``roman_inverselinearity.asdf`` (``InverselinearityRefModel``), ``coeffs`` (ncoeffs,
  ny, nx) float32, lowest order first.  romancal has no bias step: its ``linearity``
  step applies the polynomial to the raw resultants, bias included.  So the
  linearity is ``detector_reference``'s polynomial of bias-subtracted DN re-centred on
  each pixel's bias ``b`` (``x -> L(x - b)``,
  :func:`scenesim.pipelines.reffiles.shift_polynomial`): it returns linear,
  bias-free DN.  The inverse maps those back to raw DN: ``y -> b + p(y)``, the
  engine's law in DN plus the bias (exact; stcal's read-level correction uses it to
  rebuild the reads averaged into each resultant from a straight-line model, then
  linearises each read).  In float32, as stcal evaluates them, the pair reproduced
  the exact inverse to 0.013 DN over the whole well (7.7 % nonlinear at 8e4 e-, bias
  2000-8000 DN) and returned raw DN to 0.012 DN, against read noise of a few DN
  (``tests/pipelines/test_roman.py`` bounds both).
* when the scene has dark current or hot pixels, ``roman_dark.asdf`` (``DarkRefModel``:
  ``dark_slope``, DN/s, the dark rate before IPC; ``dark_slope_error`` 0).  romancal
  1.1 subtracts it from the fitted slopes, after ``ramp_fit``.

The pipeline (:func:`run_ramp_fit`)
-----------------------------------
romancal's steps in ``ExposurePipeline``'s order, each with its ``override_<type>``,
offline (CRDS disabled as in :func:`scenesim.pipelines.jwst.offline_crds`):
``DQInitStep`` (``mask``: the L1 becomes a ``RampModel``, border reference pixels set
aside), ``SaturationStep`` (``saturation``: resultants at or above the level flagged,
and the later ones), ``LinearityStep`` (``linearity`` and ``inverselinearity``, when
written), ``RampFitStep`` (``gain``, ``readnoise``), then ``DarkCurrentStep``
(``dark``, when written).  The L2 ``ImageModel`` is saved as ASDF, and ``scenesim
compare L2.asdf TRUTH`` grades it (:func:`scenesim.pipelines.products.read_roman_l2`;
when the dark step ran, the truth loses the dark the L2 names in
``meta.ref_file.dark``).

Not run, for want of a scenesim reference or of a signal to correct: ``refpix``
(scenesim writes no ``refpix`` reference, the frequency-domain weights romancal
applies to the border columns and amp33; and amp33 carries the correlated noise only
with a reference output, above), ``dark_decay`` and ``wfi18_transient``
(scenesim simulates neither effect), ``assign_wcs``, ``flatfield``, ``photom`` and what
follows (no optics).  So read an L2 of a scene with bias drifts, 1/f or pedestal noise
as "without reference-pixel correction": romancal cannot remove the noise common to a
frame (``docs/VALIDATION_PIPELINES.md`` measures what that costs on a small window).
"""

import os
import tempfile
import warnings

import numpy as np

from noise.clock import column_runs, copy_columns, detector_from_header
from noise.errors import FileFormatError, ParameterError
from noise.fitsio import record_completed
from noise.validate import check_writable

from scenesim.io.exposure import Exposure
from scenesim.io.header import readout_from_table
from scenesim.pipelines.reffiles import (check_reference_id, reference_id,
                                         shift_polynomial)

__all__ = ["write_l1", "l1_model", "l1_identity", "write_reference_files", "run_ramp_fit",
           "read_pattern", "check_amp33_detector", "AMP33_COLUMNS", "REFERENCE_TYPES",
           "REQUIRED_TYPES", "L1_IDENTITY_CARDS"]

#: Columns of the amp33 reference output (one science output's width on the WFI).
AMP33_COLUMNS = 128


def _rdm():
    try:
        import roman_datamodels.datamodels as rdd
    except ImportError as exc:              # pragma: no cover - depends on the extra
        raise ParameterError("Roman files need the optional 'roman' extra "
                             "(roman_datamodels is not installed): pip install -e "
                             "'.[roman]'") from exc
    return rdd


def read_pattern(readout):
    """romancal's ``read_pattern`` of a scenesim readout: 1-based read indices."""
    return [[int(k) + 1 for k in res] for res in readout.resultants]


def check_amp33_detector(det):
    """Refuse a detector whose reference output cannot be amp33 (module notes); a
    detector without one is accepted (the fallback amp33)."""
    if det.ref_output and (det.interleave is not None
                           or det.raw_ncols_out != AMP33_COLUMNS):
        raise ParameterError(
            f"amp33 is one reference output of {AMP33_COLUMNS} samples per row without "
            f"interleaved samples; detector {det.name!r} has a reference output of "
            f"{det.raw_ncols_out} samples per row"
            + ("" if det.interleave is None else " with 'interleave'")
            + f" (use 'n_out' = 'naxis1' / {AMP33_COLUMNS} and no 'interleave')")


def _amp33_reference_output(exp, det):
    """amp33 from the exposure's reference output (``RAWREF``; module notes): uint16 DN,
    (nresultants, ny, 128), column ``c`` the sample read at slot ``c`` of its row."""
    check_amp33_detector(det)
    _, slot, image_x = det.raw_columns()
    extra = np.flatnonzero(image_x < 0)
    rr = exp.raw_ref
    want = exp.sci.shape[:3] + (extra.size,)
    if rr is None or rr.shape != want:
        raise FileFormatError(
            f"exposure {exp.name!r} has a reference output (REFOUT) but no 'RAWREF' of "
            f"shape {want}, got {None if rr is None else rr.shape}")
    # without interleave every RAWREF column is the reference output's: time order
    order = np.argsort(slot[extra], kind="stable")
    out = np.empty(rr.shape[1:], dtype=np.uint16)
    return copy_columns(out, rr[0], column_runs(np.arange(order.size), order))


def _amp33(header, readout, t_frame, det, shape, gain, adc_top, rng):
    """The fallback amp33 samples without a reference output (module notes), uint16
    DN, (nresultants, ny, 128)."""
    from noise.params import NoiseParams
    ny = shape[0]
    rd = 0.0
    nres = readout.ngroups
    params = None
    try:
        rd = float(header.get("RDNOISE", 0.0)) if not isinstance(
            header.get("RDNOISE", 0.0), str) else 0.0
        params = NoiseParams().replace(
            rd_noise=rd, ref_ratio=float(header.get("REFRATIO", 0.8)),
            pedestal=float(header.get("PEDESTAL", 0.0)),
            bias_offset=float(header.get("BIASOFF", 0.0)))
    except (ValueError, TypeError):
        params = None
    out = np.zeros((nres, ny, AMP33_COLUMNS), dtype=np.float64)
    if params is not None:
        white = rd * params.ref_ratio
        for r, reads in enumerate(readout.resultants):
            acc = np.zeros((ny, AMP33_COLUMNS))
            for _ in reads:
                acc += rng.standard_normal((ny, AMP33_COLUMNS)) * white
                acc += rng.standard_normal() * params.pedestal
            out[r] = acc / len(reads) + params.bias_offset
    return np.clip(np.rint(out / gain), 0, adc_top).astype(np.uint16)


def l1_model(exposure, *, rng=None):
    """The Roman L1 ``ScienceRawModel`` of a scenesim exposure (module notes).

    Parameters
    ----------
    exposure : str, os.PathLike or scenesim.io.exposure.Exposure
    rng : numpy.random.Generator, int, SeedSequence or None, keyword-only
        Draws of the fallback amp33 (a detector without a reference output: module
        notes); default the exposure's seed.  Unused with a reference output, whose
        samples (``RAWREF``) are amp33.

    Raises
    ------
    noise.errors.ParameterError
        More than one integration, or a reference output that does not fit amp33.
    noise.errors.FileFormatError
        A reference output without its ``RAWREF`` samples.
    """
    rdd = _rdm()
    exp = exposure if isinstance(exposure, Exposure) else Exposure.read(exposure)
    hdr = exp.header
    det = detector_from_header(hdr)
    ro = readout_from_table(hdr, exp.reads)
    if ro.nints != 1:
        raise ParameterError(f"a Roman L1 file holds one integration; the exposure has "
                             f"nints = {ro.nints}")
    amp33 = _amp33_reference_output(exp, det) if det.ref_output else None
    t_frame = float(hdr["TFRAME"])
    gain = float(hdr["GAIN"])
    sci = np.asarray(exp.sci[0], dtype=np.uint16)
    nres, ny, nx = sci.shape
    if rng is None:
        rng = np.random.SeedSequence(int(hdr.get("SEED", 0)), spawn_key=(33,))
    rng = np.random.default_rng(rng)
    m = rdd.ScienceRawModel.create_fake_data(shape=(nres, ny, nx))
    m.data = sci
    if amp33 is not None:
        m.amp33 = amp33
    else:
        m.amp33 = _amp33(hdr, ro, t_frame, det, (ny, nx), gain,
                         int(2 ** int(hdr.get("ADCBITS", 16)) - 1), rng)
    ex = m.meta.exposure
    ex.type = "WFI_IMAGE"
    ex.read_pattern = read_pattern(ro)
    ex.nresultants = nres
    ex.frame_time = t_frame
    ex.ma_table_name = ro.name
    ex.ma_table_number = 0
    tbar = ro.mean_times(t_frame)
    ex.exposure_time = float((ro.nreads + 1) * t_frame)
    ex.effective_exposure_time = float(tbar[-1] - tbar[0])
    # the fake model's start time stays; the end follows it by the exposure time
    # (create_fake_data sets both to the same instant)
    from astropy.time import TimeDelta
    ex.end_time = ex.start_time + TimeDelta(ex.exposure_time, format="sec")
    m.meta.filename = "l1.asdf"
    # the exposure's identity, which 'scenesim pipeline roman --truth' compares with
    # the truth before romancal runs
    m.meta["scenesim_cards"] = {k: _asdf_card(hdr[k]) for k in L1_IDENTITY_CARDS
                                if k in hdr}
    return m


def _save_asdf(model, path, overwrite):
    """Write ``model`` to ``path`` atomically: into a hidden temporary directory beside
    it under its final name (the models record the name they are written under),
    then renamed into place."""
    path = os.fspath(path)
    check_writable("output path", path, overwrite=overwrite)
    parent = os.path.dirname(os.path.abspath(path))
    with tempfile.TemporaryDirectory(prefix=".scenesim-", dir=parent) as tmpdir:
        tmp = os.path.join(tmpdir, os.path.basename(path))
        model.to_asdf(tmp)
        os.replace(tmp, path)
        record_completed(path)


def write_l1(exposure, path, *, overwrite=False, reference_id=None):
    """Write the Roman L1 ASDF file of a scenesim exposure; returns ``path``.

    ``reference_id``: :func:`scenesim.pipelines.reffiles.reference_id` of the run's
    references, recorded as ``meta.scenesim_refid`` (:func:`run_ramp_fit` refuses
    references with another)."""
    path = check_writable("L1 path", path, overwrite=overwrite)
    if not os.fspath(path).lower().endswith(".asdf"):
        raise ParameterError(f"'path' of a Roman L1 file must end in '.asdf', got "
                             f"{os.fspath(path)!r}")
    m = l1_model(exposure)
    if reference_id is not None:
        m.meta["scenesim_refid"] = str(reference_id)
    m.validate()
    _save_asdf(m, path, overwrite)
    return path


#: Cards of the exposure an L1 records in ``meta.scenesim_cards`` (:func:`write_l1`),
#: the identity :func:`l1_identity` gives.
L1_IDENTITY_CARDS = ("SEED", "SEEDENT", "SCENEID", "GAIN")


def _asdf_card(value):
    """A header card's value as ASDF stores it: an integer beyond 64 bits as its
    decimal string."""
    if isinstance(value, (int, np.integer)) and not -2 ** 63 <= int(value) < 2 ** 63:
        return str(value)
    return value.item() if isinstance(value, np.generic) else value


def l1_identity(path):
    """``(header, (ny, nx))`` of an L1 file (:func:`check_l1_file`): the FITS-like
    cards of its exposure that a truth file also has (``NINTS`` 1, ``NGROUPS``
    (resultants), ``READPATT`` (the MA table's name), ``TFRAME``, and the
    ``meta.scenesim_cards`` of :func:`write_l1`: ``SEED``, ``SEEDENT``, ``SCENEID``,
    ``GAIN``; an L1 written before it had them has only the first four) and its image
    shape."""
    from astropy.io import fits
    hdr = fits.Header()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with _rdm().open(os.fspath(path)) as m:
            shape = tuple(int(n) for n in np.shape(m.data)[-2:])
            ex = m.meta.get("exposure", {})
            for key, name in (("READPATT", "ma_table_name"), ("NGROUPS", "nresultants"),
                              ("TFRAME", "frame_time")):
                value = ex.get(name) if hasattr(ex, "get") else None
                if value is not None and not (isinstance(value, str)
                                              and value.strip() in ("", "?")):
                    hdr[key] = value
            hdr["NINTS"] = 1
            cards = m.meta.get("scenesim_cards", {}) or {}
            for key in L1_IDENTITY_CARDS:
                if key in cards:
                    hdr[key] = cards[key]
    return hdr, shape


#: Roman reference types written by :func:`write_reference_files` (the last three only
#: for a nonlinear detector, or one with a dark).
REFERENCE_TYPES = ("gain", "readnoise", "mask", "saturation", "linearity",
                   "inverselinearity", "dark")

#: Reference types every :func:`run_ramp_fit` needs.
REQUIRED_TYPES = ("gain", "readnoise", "mask")


def _reference_arrays(reference):
    """``{reftype: {field: array}}`` of the Roman references of ``reference``
    (module notes): only the types this detector needs."""
    shape = reference.detector.shape
    g = reference.gain
    f32 = np.float32
    zeros_dq = np.zeros(shape, dtype=np.uint32)
    arrays = {"gain": {"data": np.full(shape, g, dtype=f32)},
              "readnoise": {"data": (reference.read_noise / g).astype(f32)},
              "mask": {"dq": reference.mask.astype(np.uint32)},
              "saturation": {"data": (reference.saturation / g).astype(f32),
                             "dq": zeros_dq}}
    linear = (reference.linearity.tolist() == [0.0, 1.0]
              and reference.nonlinearity.tolist() == [0.0, 1.0])
    if not linear:
        bias_dn = reference.bias / g
        inverse = np.empty((reference.nonlinearity.size,) + shape, dtype=f32)
        inverse[:] = reference.nonlinearity[:, None, None]
        inverse[0] = reference.nonlinearity[0] + bias_dn
        arrays["linearity"] = {"coeffs": shift_polynomial(reference.linearity, bias_dn,
                                                          dtype=f32),
                               "dq": zeros_dq}
        arrays["inverselinearity"] = {"coeffs": inverse, "dq": zeros_dq}
    if np.any(reference.dark != 0):
        arrays["dark"] = {"dark_slope": (reference.dark / g).astype(f32),
                          "dark_slope_error": np.zeros(shape, dtype=f32),
                          "dq": zeros_dq}
    return arrays


def write_reference_files(reference, directory, *, overwrite=False):
    """Write ``roman_<type>.asdf`` for each of :data:`REFERENCE_TYPES` the detector
    needs (module notes); each model is validated before it is written.

    Parameters
    ----------
    reference : scenesim.pipelines.reffiles.DetectorReference
    directory : str or os.PathLike
        Created if missing.
    overwrite : bool, keyword-only
        Replace existing files (default: refuse, before any is written).

    Returns
    -------
    dict
        ``{reftype: path}`` of the files written.  A ``roman_<type>.asdf`` this
        detector does not need (a linearity pair from an earlier nonlinear run) is
        removed with ``overwrite``, since a pipeline run picks up every file of the
        directory.
    """
    rdd = _rdm()
    arrays = _reference_arrays(reference)
    os.makedirs(directory, exist_ok=True)
    every = {t: os.path.join(os.fspath(directory), f"roman_{t}.asdf")
             for t in REFERENCE_TYPES}
    for t, p in every.items():
        check_writable(f"{t} reference", p, overwrite=overwrite)
    for t, p in every.items():
        if t not in arrays and os.path.exists(p):
            os.remove(p)
    paths = {t: every[t] for t in arrays}
    classes = {"gain": rdd.GainRefModel, "readnoise": rdd.ReadnoiseRefModel,
               "mask": rdd.MaskRefModel, "saturation": rdd.SaturationRefModel,
               "linearity": rdd.LinearityRefModel,
               "inverselinearity": rdd.InverselinearityRefModel,
               "dark": rdd.DarkRefModel}
    for t, fields in arrays.items():
        first = next(iter(fields.values()))
        m = classes[t].create_fake_data(shape=first.shape)
        for name, value in fields.items():
            setattr(m, name, value)
        m.meta.description = f"scenesim: {t} of the simulated detector"
        m.meta["scenesim_refid"] = reference_id(reference)
        m.meta.author = "scenesim"
        m.meta.pedigree = "DUMMY"
        m.validate()
        _save_asdf(m, paths[t], overwrite)
    return paths


def _step(step_class, **kwargs):
    """A romancal step with every reference it reads overridden: the given paths, and
    ``'N/A'`` (stpipe's "no reference": the step skips that part) for the types
    scenesim does not write (the linearity step's ``integralnonlinearity``): a type
    left to CRDS would make crds end the process with ``sys.exit(-1)`` offline."""
    refs = {t: kwargs.pop(t) for t in list(kwargs) if t in step_class.reference_file_types}
    overrides = {f"override_{t}": os.fspath(refs[t]) if t in refs else "N/A"
                 for t in step_class.reference_file_types}
    step = step_class(**overrides, **kwargs)
    step.prefetch_references = False
    return step


def _run_step(step_class, model, **references):
    return _step(step_class, **references).run(model)


def _l1_resultants(path):
    """Number of resultants of the L1 file ``path`` (checked by
    :func:`check_l1_file`)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with _rdm().open(path) as model:
            return int(np.shape(model.data)[0])


def check_l1_file(path):
    """Raise unless ``path`` is an existing Roman L1 (``ScienceRawModel``) ASDF file."""
    from noise.validate import check_existing_file
    path = check_existing_file("L1", path)
    rdd = _rdm()
    try:
        with warnings.catch_warnings():    # e.g. meta.filename of a renamed copy
            warnings.simplefilter("ignore")
            with rdd.open(path) as model:
                kind, shape = type(model).__name__, np.shape(model.data)
                if kind == "ScienceRawModel" and len(shape) == 3:
                    # the blocks load lazily: read the ramp now, so that a damaged
                    # or cut file is refused here, not inside romancal
                    np.asarray(model.data).sum(dtype=np.float64)
    except Exception as exc:                 # not ASDF, or not a Roman data model
        raise FileFormatError(
            f"L1 {path!r} is not a Roman ASDF data model ({type(exc).__name__}: "
            f"{str(exc).splitlines()[0] if str(exc) else ''}); write one with "
            f"'scenesim run SCENE --l1'") from exc
    if kind != "ScienceRawModel" or len(shape) != 3:
        raise FileFormatError(
            f"L1 {path!r} holds a {kind} of shape {shape}, not an L1 ramp "
            f"(ScienceRawModel, (nresultants, ny, nx)); write one with 'scenesim run "
            f"SCENE --l1'")
    return path


def _check_references_match(l1, references):
    """Raise unless every reference is of the L1's detector and image size (a set
    written for another array broke inside romancal with a numpy broadcast error; one
    of another detector of the same size ran without a word)."""
    rdd = _rdm()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rdd.open(l1) as m:
            detector = str(m.meta.instrument.detector)
            shape = tuple(np.shape(m.data)[-2:])
            run_id = m.meta.get("scenesim_refid")
        for reftype, ref in sorted(references.items()):
            try:
                with rdd.open(os.fspath(ref)) as r:
                    theirs = str(r.meta.instrument.detector)
                    their_id = r.meta.get("scenesim_refid")
                    arrays = [k for k in ("data", "dq", "dark_slope") if k in r]
                    ref_shape = tuple(np.shape(r[arrays[0]])[-2:]) if arrays else None
            except Exception as exc:                  # noqa: BLE001 - asdf's many
                raise FileFormatError(f"{reftype} reference {os.fspath(ref)!r} is not a "
                                      f"Roman reference file ({type(exc).__name__}: "
                                      f"{str(exc).splitlines()[0] if str(exc) else ''})"
                                      ) from exc
            if theirs != detector:
                raise ParameterError(
                    f"{reftype} reference {os.fspath(ref)!r} is for detector {theirs!r}, "
                    f"the L1 {os.fspath(l1)!r} for {detector!r}")
            if ref_shape is not None and ref_shape != shape:
                raise ParameterError(
                    f"{reftype} reference {os.fspath(ref)!r} is {ref_shape[0]} x "
                    f"{ref_shape[1]} pixels, the L1 {os.fspath(l1)!r} {shape[0]} x "
                    f"{shape[1]}: references of another array (write them with "
                    f"'scenesim run SCENE --reffiles')")
            check_reference_id(reftype, ref, their_id, "L1", l1, run_id)


#: Fewest resultants romancal's ``likely`` fit takes (stcal's likelihood fit).
LIKELY_MIN_RESULTANTS = 4


def run_ramp_fit(l1, references, path, *, algorithm=None, overwrite=False,
                 inputs=()):
    """Calibrate a Roman L1 file with romancal, offline; write the L2 ASDF.

    Runs ``dq_init``, ``saturation``, ``linearity``, ``ramp_fit`` and ``dark_current``
    in ``ExposurePipeline``'s order, each step whose references are given (module
    notes).

    Parameters
    ----------
    l1 : str
        L1 ASDF file (:func:`write_l1`).
    references : dict
        ``{'gain': path, 'readnoise': path, 'mask': path}`` and, optionally,
        ``'saturation'``, ``'linearity'`` with ``'inverselinearity'``, and ``'dark'``
        (:func:`write_reference_files`); a step whose references are missing is not
        run.
    path : str
        Output L2 ``.asdf`` file.
    algorithm : {'likely', 'ols_cas22'} or None, keyword-only
        romancal's fitter (``ols_cas22`` is deprecated in romancal 1.1).  None
        (default): ``likely``, or ``ols_cas22`` for an L1 of fewer than
        :data:`LIKELY_MIN_RESULTANTS` resultants, which ``likely`` refuses (a probe:
        a 3-resultant table ended in stcal's traceback).  An L1 of one resultant is
        refused: no slope.
    overwrite : bool, keyword-only
    inputs : sequence of str, keyword-only
        Other files the caller reads (a truth, an exposure): like the L1 and the
        references, never replaced by the L2, even with ``overwrite``.

    Returns
    -------
    str
        ``path``.
    """
    rdd = _rdm()
    l1 = check_l1_file(l1)
    missing = [t for t in REQUIRED_TYPES if t not in references]
    if missing:
        raise ParameterError(f"'references' lacks {missing}; write them with "
                             f"write_reference_files")
    if ("linearity" in references) != ("inverselinearity" in references):
        raise ParameterError(f"'references' must give both 'linearity' and "
                             f"'inverselinearity' (romancal's linearity step reads "
                             f"both) or neither, got {sorted(references)}")
    if algorithm not in (None, "likely", "ols_cas22"):
        raise ParameterError(f"'algorithm' must be 'likely', 'ols_cas22' or None, got "
                             f"{algorithm!r}")
    nres = _l1_resultants(l1)
    if nres < 2:
        raise ParameterError(f"L1 {l1!r} has {nres} resultant: a ramp fit needs at "
                             f"least 2")
    if algorithm is None:
        algorithm = "likely" if nres >= LIKELY_MIN_RESULTANTS else "ols_cas22"
    elif algorithm == "likely" and nres < LIKELY_MIN_RESULTANTS:
        raise ParameterError(
            f"'algorithm' 'likely' needs at least {LIKELY_MIN_RESULTANTS} resultants; "
            f"L1 {l1!r} has {nres}: use 'ols_cas22' (or None, which chooses it)")
    _check_references_match(l1, references)
    from scenesim.outputs import check_outputs
    # never the L1 or a reference, even with overwrite
    read = [l1, *map(os.fspath, references.values()), *map(os.fspath, inputs)]
    path = check_outputs({"L2 file": path}, inputs=read, overwrite=overwrite,
                         endings={"L2 file": (".asdf",)})["L2 file"]
    from scenesim.pipelines.jwst import offline_crds
    with offline_crds():
        from romancal.dark_current import DarkCurrentStep
        from romancal.dq_init import DQInitStep
        from romancal.linearity import LinearityStep
        from romancal.ramp_fitting import RampFitStep
        from romancal.saturation import SaturationStep
        model = _run_step(DQInitStep, os.fspath(l1), mask=references["mask"])
        if "saturation" in references:
            model = _run_step(SaturationStep, model, saturation=references["saturation"])
        if "linearity" in references:
            model = _run_step(LinearityStep, model, linearity=references["linearity"],
                              inverselinearity=references["inverselinearity"])
        result = _step(RampFitStep, algorithm=algorithm, include_var_rnoise=True,
                       gain=references["gain"],
                       readnoise=references["readnoise"]).run(model)
        if "dark" in references:
            result = _run_step(DarkCurrentStep, result, dark=references["dark"])
    # an L2 file requires 'wcs' (null allowed) and 'photometry', which romancal's
    # assign_wcs and photom steps (not run: no scenesim references) would add
    meta = result.meta
    if "wcs" not in meta:
        meta["wcs"] = None
    if "photometry" not in meta:
        meta["photometry"] = rdd.ImageModel.create_fake_data(
            shape=result.data.shape).meta.photometry
    _save_asdf(result, path, overwrite)
    return path
