"""Run the JWST calibration library's ramp fitting (stcal) on a scenesim exposure.

:func:`fit_exposure_stcal` takes an exposure (a file written by scenesim, or the
same contents in memory), runs *the same* pre-processing as
:func:`scenesim.calib.prepare.fit_exposure_file` -- literally the same function,
:func:`scenesim.calib.prepare.prepare_exposure`: DN to e- with ``GAIN``, IPC undone when
the header records its kernel (``IPCKERN``), saturation flags on the estimated last
read of each resultant, reference correction, the classical nonlinearity inverted
(``NLCOEFF``), removal of the per-output common mode and the per-column read noise
measured from the ramps --
hands the resulting ramps (the e- cube divided by ``GAIN``, in DN) and that same
read-noise map (converted with :func:`stcal_read_noise`) to
``stcal.ramp_fitting.ramp_fit.ramp_fit_data``, and writes the rates in scenesim's
own slope-file layout (:func:`scenesim.io.fitfile.write_fit`).  Both fitters therefore see
identical data and noise model, so ``scenesim compare`` of the two slope files
isolates the fitter.  ``remove_common_mode`` / ``measure_noise`` switch the two
data-driven steps off for both alike.  stcal is an optional dependency
(``pip install 'scenesim[stcal]'``), imported only inside :func:`fit_exposure_stcal`.
Written against stcal 1.20.0.

Conventions, scenesim -> stcal (stated explicitly)
--------------------------------------------------
============  ====================================  ====================================
quantity      scenesim                              stcal 1.20 (``RampData``, arguments)
============  ====================================  ====================================
ramps         ``SCI`` uint16 DN,                    ``data`` float32 DN, same axes
              (nints, ngroups, ny, nx)              (``RampModel.data`` layout): no
                                                    transpose.  We pass the prepared
                                                    e- cube (``prepare_exposure``)
                                                    divided by ``GAIN``.
gain          ``GAIN`` e-/DN (scalar)               ``gain_2d`` float32 (ny, nx) e-/DN
read noise    sigma, white noise of ONE read, e-    ``readnoise_2d`` float32 (ny, nx):
              (not CDS): the per-column map         the CDS noise of two single frames,
              measured by ``prepare_exposure``      in DN: ``sqrt(2) * sigma / GAIN``
              (``RDNOISE`` if ``measure_noise``     (:func:`stcal_read_noise`), pixel
              is False)                             by pixel
read times    read k (0-based, from reset) at       ``frame_time`` = ``TFRAME``;
              ``(k + 1) t_frame``; ``READS`` table  ``nframes`` = reads in resultant 0;
              holds every resultant's reads         ``group_time`` = spacing of the mean
                                                    read times (``(nframes + groupgap)
                                                    t_frame`` for MULTIACCUM);
                                                    ``groupgap`` = first read of group 1
                                                    - first read of group 0 - nframes;
                                                    ``drop_frames1`` = first read index.
                                                    LIKELY: ``read_pattern`` = list of
                                                    per-resultant read-time arrays, s.
saturation    bool per resultant, sticky            ``groupdq`` uint8
                                                    ``SATURATED | DO_NOT_USE`` (what the
                                                    JWST saturation step writes)
1 good group  pixel ``DO_NOT_USE`` (zero point      ``suppress_one_group_ramps = True``
              unknown without a superbias)          (such ramps count as unusable)
output        e-/s, (e-/s)^2                        DN/s, (DN/s)^2: multiplied by
                                                    ``GAIN`` and ``GAIN**2``
============  ====================================  ====================================

What stcal does with the read noise (from its source, stcal 1.20.0):

* ``OLS_C`` multiplies ``readnoise_2d`` **in place** by ``gain / sqrt(2 nframes)``,
  i.e. it works with the noise of one group average in e-, ``sigma / sqrt(nframes)``
  (the adapter always passes a fresh array).  Its read-noise variance of a segment of
  ``N`` groups is the equal-weight least-squares value
  ``12 sigma^2 / (nframes t_group^2 (N^3 - N))``, which equals
  :func:`scenesim.rampfit.variance.ols_variance` at rate 0 for a MULTIACCUM readout.
* ``LIKELY`` divides ``readnoise_2d`` by ``sqrt(2)``: ``sigma / GAIN`` DN per read, the
  read noise of Brandt (2024, PASP 136, 045004, eqs. 28-29) with per-resultant read
  counts taken from ``read_pattern``.

So ``readnoise_2d = sqrt(2) sigma / GAIN`` is exact for both.  A global reset shifts
every read time of a pixel by the same amount; both fitters use only differences of
read times, so the rolling-reset times are passed.

Algorithms
----------
``'OLS_C'``
    stcal's C least-squares fitter (the default of the JWST pipeline).  Groups must be
    evenly spaced and equal in size (``Readout.is_uniform``): it regresses against the
    group index times ``group_time``; uneven (Roman-style) tables raise
    :class:`~noise.errors.ParameterError`.  Weights are the "optimal" power-law weights
    of Fixsen et al. (2000, PASP 112, 1350): ``|i - i_mid|^P`` with ``P`` = 0, 0.4, 1,
    3, 6, 10 for a segment signal-to-noise ratio below 5, 10, 20, 50, 100 and above
    (``weighting='optimal'``, the only value stcal 1.20 accepts, so it is not a
    parameter here).  The reported variance is ``var_rnoise`` above plus
    ``var_poisson = median_rate / (t_group * gain * (N - 1))``, whatever ``P``.
    stcal's jump step is *not* run: cosmic rays are not excluded (``JUMP_DET`` never
    set).  stcal 1.20 has no separate Python ``'OLS'`` fitter any more (any name other
    than ``'LIKELY'`` runs ``OLS_C``), so ``'OLS'`` is rejected rather than silently
    aliased.
``'LIKELY'``
    The likelihood (optimal GLS) fitter of Brandt (2024, PASP 136, 045004 and 045005)
    on resultant differences, with the covariance at a rate guess (a first fit that
    starts from the median difference, clipped at 0), for any readout through
    ``read_pattern``.  It needs at least 4 resultants (stcal otherwise switches
    silently to ``OLS_C``; the adapter raises instead).  It always runs its own jump
    detection (chi-square improvement above 20.25, i.e. 4.5 sigma, for one omitted
    difference, above 23.8 for two); flagged groups are counted in ``n_jumps`` and
    set ``JUMP_DET``.  Several integrations are combined by stcal (median, then two
    inverse-variance re-weightings).

Output
------
The slope file has every extension of :meth:`scenesim.io.fitfile.FitResult.to_hdul`, with
``FITTER = 'stcal-OLS_C'`` or ``'stcal-LIKELY'``, ``STCALVER`` (stcal version), the
conversion cards ``RNSTCAL`` (the median ``readnoise_2d`` value, DN CDS) and
``RNCONV``, and the pre-processing cards of :func:`scenesim.calib.prepare.prepare_exposure`
(``REFPIX``, ``RNMODEL``, ``RNSOURCE``, ``CMREMOVE``, ...); ``RNOISE`` is the
median read noise handed to stcal, e- per read.
``SLOPE`` is stcal's combined rate times ``GAIN``; ``VAR_READ`` / ``VAR_POIS`` are
stcal's ``var_rnoise`` / ``var_poisson`` times ``GAIN**2`` (so ``chi2_rep`` in the
comparison tests stcal's own error estimate); ``SLOPEINT`` / ``VARINT`` come from its
per-integration products.

``CHI2`` is *not* an stcal output (``OLS_C`` computes none; ``LIKELY``'s is per
integration around per-integration rates).  To give every fitter the same
diagnostic, it is computed here exactly as :mod:`scenesim.rampfit.fitter` defines it, with
:func:`scenesim.rampfit.variance.model_chi2`: the chi-square of the rate estimates
``d_i = (R_{i+1} - R_i)/dt_i`` (in e-, the prepared cube) around stcal's combined
rate ``f``, under the model covariance of Brandt (2024, eqs. 28-29) at ``max(f, 0)``
with the read noise ``sigma`` handed to stcal, summed over integrations and divided
by ``DOF`` = usable differences - 1.  Usable
differences: both resultants free of ``SATURATED``/``DO_NOT_USE`` in stcal's final
group DQ and the later one not ``JUMP_DET``.  Its expectation is
``1 + (V/V_opt - 1)/DOF`` for a linear unbiased fitter of variance ``V`` (1 for the
optimal one).

Unmeasured pixels (no usable difference in any integration, or a non-finite stcal
result) follow scenesim's rules: ``DO_NOT_USE``, slope 0, ``VAR_READ`` =
``BAD_VARIANCE``, never NaN.  Reference pixels are flagged
``REFERENCE_PIXEL | DO_NOT_USE``; ``SATURATED`` is set where any resultant is
saturated.

Measured accuracy against scenesim's GLS and the cost are in
``docs/VALIDATION_FIT.md``.
"""

import inspect
import math
from dataclasses import replace

import numpy as np

from noise.errors import ParameterError
from noise.validate import check_array, check_writable

from scenesim.calib.prepare import PrepareOptions, load_exposure, prepare_exposure
from scenesim.detector.dq import (BAD_VARIANCE, DO_NOT_USE, JUMP_DET, REFERENCE_PIXEL,
                                  SATURATED)
from scenesim.io.fitfile import FitResult, write_fit
from scenesim.io.header import exposure_read_noise, exposure_readout
from scenesim.rampfit.variance import model_chi2

__all__ = ["STCAL_ALGORITHMS", "fit_exposure_stcal", "stcal_read_noise"]

#: stcal ramp-fitting algorithms accepted by :func:`fit_exposure_stcal`.
STCAL_ALGORITHMS = ("OLS_C", "LIKELY")

#: JWST data-quality bits handed to stcal (``RampData.set_dqflags``).
_DQFLAGS = {
    "GOOD": 0,
    "DO_NOT_USE": DO_NOT_USE,
    "SATURATED": SATURATED,
    "JUMP_DET": JUMP_DET,
    "PERSISTENCE": 2 ** 5,
    "CHARGELOSS": 2 ** 7,
    "NO_GAIN_VALUE": 2 ** 19,
    "UNRELIABLE_SLOPE": 2 ** 24,
}

_LIKELY_MIN_NGROUPS = 4           # stcal.ramp_fitting.likely_fit.LIKELY_MIN_NGROUPS
_LIKELY_JUMP_SIGMA = math.sqrt(20.25)   # stcal's default one-omit threshold, sigma
_F32 = np.float32
_RAMP_FIT_ARGS = ("ramp_data", "save_opt", "readnoise_2d", "gain_2d", "algorithm",
                  "weighting", "max_cores")
_NOISELESS_HINT = ("stcal divides by the read noise; pass read_noise > 0 (e- per "
                   "read) in PrepareOptions for a noiseless exposure")


def stcal_read_noise(read_noise, gain):
    """Convert scenesim's read noise to the ``readnoise_2d`` value stcal expects.

    Parameters
    ----------
    read_noise : float or ndarray
        White read noise of ONE read, e- (scenesim's ``RDNOISE``; not CDS), >= 0.
    gain : float or ndarray
        e-/DN, > 0.

    Returns
    -------
    float or ndarray (float64)
        CDS read noise of two single frames in DN, ``sqrt(2) * read_noise / gain``.
    """
    rn = check_array("read_noise", read_noise, minimum=0.0, unit="e- per read")
    g = check_array("gain", gain, minimum=0.0, strict_min=True, unit="e-/DN")
    out = math.sqrt(2.0) * rn / g
    return float(out) if out.ndim == 0 else out


def _import_stcal():
    """Import stcal's ramp fitting lazily; clear ImportError if missing/incompatible.

    Lazy on purpose: stcal is an optional, heavy dependency, and importing this
    adapter must not import it.
    """
    try:
        import stcal
        from stcal.ramp_fitting.ramp_fit import ramp_fit_data
        from stcal.ramp_fitting.ramp_fit_class import RampData
    except ImportError as exc:
        raise ImportError(
            "fit_exposure_stcal needs the optional dependency stcal (the JWST "
            "calibration library); install it with: pip install 'scenesim[stcal]'"
        ) from exc
    version = str(getattr(stcal, "__version__", "unknown"))
    params = tuple(inspect.signature(ramp_fit_data).parameters)
    if params != _RAMP_FIT_ARGS:
        raise ImportError(
            f"stcal {version} has ramp_fit_data{params}; scenesim's adapter was "
            f"written for the stcal 1.20 signature {_RAMP_FIT_ARGS}; install the "
            f"tested version with: pip install 'stcal~=1.20'")
    return ramp_fit_data, RampData, version


def _check_algorithm(algorithm):
    """The stcal name of ``algorithm`` (case-insensitive), or raise."""
    alg = algorithm.upper() if isinstance(algorithm, str) else None
    if alg not in STCAL_ALGORITHMS:
        hint = ""
        if alg == "OLS":
            hint = ("; stcal 1.20 has no separate Python 'OLS' fitter (it would run "
                    "'OLS_C'), use 'OLS_C'")
        raise ParameterError(
            f"'algorithm' must be one of {list(STCAL_ALGORITHMS)} (stcal names), got "
            f"{algorithm!r}{hint}")
    return alg


def _check_readout(alg, ro):
    """Raise ParameterError if stcal's ``alg`` cannot fit this readout exactly."""
    if ro.ngroups < 2:
        raise ParameterError(
            f"stcal needs >= 2 resultants for a slope (the one-group path needs a "
            f"superbias-subtracted ramp); this exposure has {ro.ngroups}")
    if alg == "OLS_C" and not ro.is_uniform:
        raise ParameterError(
            f"'algorithm'='OLS_C' fits evenly spaced groups of equal size only; "
            f"readout {ro.name!r} has uneven resultants "
            f"{[len(r) for r in ro.resultants]} starting at reads "
            f"{[r[0] for r in ro.resultants]}; use 'LIKELY' (it takes the read times "
            f"of every resultant)")
    if alg == "LIKELY" and ro.ngroups < _LIKELY_MIN_NGROUPS:
        raise ParameterError(
            f"'algorithm'='LIKELY' needs >= {_LIKELY_MIN_NGROUPS} resultants (stcal "
            f"would switch to 'OLS_C'); this exposure has {ro.ngroups}")


def _timing(ro, t_frame):
    """stcal's MULTIACCUM metadata: (nframes, groupgap, group_time s, drop_frames1)."""
    nframes = len(ro.resultants[0])
    first = [r[0] for r in ro.resultants]
    groupgap = first[1] - first[0] - nframes
    return nframes, groupgap, float(ro.tgroup(t_frame)), first[0]


def fit_exposure_stcal(exposure, output, *, algorithm="OLS_C", overwrite=False,
                       options=PrepareOptions()):
    """Fit the ramps of a scenesim exposure with stcal and write a scenesim slope file.

    Parameters
    ----------
    exposure : str, os.PathLike or scenesim.io.exposure.Exposure
        Exposure written by scenesim (``SCI`` uint16 DN (nints, ngroups, ny, nx) and
        ``READS`` table), or the same contents in memory.
    output : str or os.PathLike
        Slope file to write (scenesim layout, :func:`scenesim.io.fitfile.write_fit`,
        written atomically).
    algorithm : {'OLS_C', 'LIKELY'}, keyword-only
        stcal ramp-fitting algorithm (case-insensitive); see the module notes.
        ``'OLS_C'`` needs evenly spaced, equal groups; ``'LIKELY'`` >= 4 resultants.
    overwrite : bool, keyword-only
        Replace an existing ``output`` (default: refuse it).
    options : scenesim.calib.prepare.PrepareOptions, keyword-only
        The pre-processing, the very one of
        :func:`scenesim.calib.prepare.fit_exposure_file` (same defaults).  Its
        ``read_noise`` (e- per read, not CDS; default the header's ``RDNOISE``) is
        passed to stcal as ``sqrt(2) * read_noise / GAIN`` DN, per column when
        ``measure_noise``.  stcal divides by it, so a noiseless exposure needs an
        explicit value > 0 (any value > 0 gives a linear unbiased fit).  Its
        ``threads`` run the pre-processing; stcal itself runs on one core.

    Returns
    -------
    scenesim.io.fitfile.FitResult
        ``fitter`` = ``'stcal-OLS_C'`` or ``'stcal-LIKELY'``; rates in e-/s,
        variances in (e-/s)^2, ``read_noise`` (median of the map handed to stcal)
        in e- per read.

    Raises
    ------
    noise.errors.ParameterError
        Unknown ``algorithm``, bad ``options``, a read noise of 0, an unwritable
        ``output``, or a readout the algorithm cannot fit (before any fitting).
    noise.errors.FileFormatError
        Missing or malformed exposure file.
    ImportError
        stcal is not installed (``pip install 'scenesim[stcal]'``) or has an
        incompatible ``ramp_fit_data``.
    """
    alg = _check_algorithm(algorithm)
    if not isinstance(options, PrepareOptions):
        raise ParameterError(
            f"'options' must be a scenesim.calib.prepare.PrepareOptions, got "
            f"{type(options).__name__}")
    if options.read_noise == 0:
        raise ParameterError(f"'read_noise' must be > 0, got 0.0; {_NOISELESS_HINT}")
    ramp_fit_data, RampData, version = _import_stcal()
    check_writable("output", output, overwrite=overwrite)
    exp = load_exposure(exposure)
    _check_readout(alg, exposure_readout(exp))
    rdn = exposure_read_noise(exp.header) if options.read_noise is None \
        else options.read_noise
    if not (math.isfinite(rdn) and rdn > 0):
        raise ParameterError(
            f"header RDNOISE of {exp.name!r} is {rdn!r}; {_NOISELESS_HINT}")

    # ---- pre-processing: the one of scenesim.calib.prepare.fit_exposure_file (in e-)
    prep = prepare_exposure(exp, options=replace(options, read_noise=rdn))
    rd, times = _ramp_data(RampData, prep, alg)
    rn_dn = stcal_read_noise(prep.read_noise, prep.gain)
    ny, nx = prep.electrons.shape[-2:]
    # a fresh array: stcal scales it in place
    readnoise_2d = np.empty((ny, nx), _F32)
    readnoise_2d[...] = rn_dn
    gain_2d = np.full((ny, nx), prep.gain, _F32)
    image, integ, _ = ramp_fit_data(rd, False, readnoise_2d, gain_2d, alg, "optimal",
                                    "none")
    result = _to_fit_result(prep, rd, image, integ, times, alg)
    cards = [("FITTER", f"stcal-{alg}", "stcal ramp_fit_data algorithm"),
             ("STCALVER", version, "stcal version"),
             ("JUMPTHR", _LIKELY_JUMP_SIGMA if alg == "LIKELY" else 0.0,
              "[sigma] jump threshold, 0=off"),
             ("RNSTCAL", float(np.median(rn_dn)),
              "[DN] stcal readnoise_2d, median: sqrt2*RN/GAIN"),
             ("CHI2DEF", "scenesim model", "CHI2: scenesim model chi2, not stcal's")]
    # RSNOISE says what scenesim's covariance holds: here only the recomputed CHI2
    # uses it, stcal's errors do not (a probe read the card as theirs)
    cards += [(k, v, "[e-] rounding: in CHI2, not in stcal errors" if k == "RSNOISE"
               else c) for k, v, c in prep.cards]
    write_fit(output, result, header_cards=cards, overwrite=overwrite)
    return result


def _ramp_data(RampData, prep, alg):
    """stcal's ``RampData`` of the prepared exposure (DN float32 in the SCI layout,
    JWST group DQ, MULTIACCUM metadata) and the rolling-reset read times."""
    ro, t_frame = prep.readout, prep.t_frame
    ny = prep.electrons.shape[-2]
    data = prep.electrons / _F32(prep.gain)
    gdq = np.where(prep.saturated, np.uint8(_DQFLAGS["SATURATED"] | _DQFLAGS["DO_NOT_USE"]),
                   np.uint8(0)).astype(np.uint8)
    nframes, groupgap, group_time, drop1 = _timing(ro, t_frame)
    times = ro.read_times(t_frame)          # rolling-reset times; see module notes
    rd = RampData()
    rd.set_arrays(data, gdq, np.zeros(prep.electrons.shape[-2:], np.uint32),
                  np.zeros(prep.electrons.shape[-2:], _F32))
    rd.set_meta(name=prep.detector.name, frame_time=t_frame,
                group_time=group_time, groupgap=groupgap, nframes=nframes,
                drop_frames1=drop1)
    rd.algorithm = alg
    rd.set_dqflags(_DQFLAGS)
    rd.start_row = 0
    rd.num_rows = ny
    rd.suppress_one_group_ramps = True
    if alg == "LIKELY":
        rd.read_pattern = [np.asarray(t, dtype=float) for t in times]
    return rd, times


def _to_fit_result(prep, rd, image, integ, times, alg):
    """stcal's products back in scenesim's conventions (e-, e-/s) as a FitResult."""
    e, sat, gain = prep.electrons, prep.saturated, prep.gain
    nints, _, ny, nx = e.shape
    g = _F32(gain)
    g2 = _F32(gain * gain)
    fgdq = np.asarray(rd.groupdq)
    bad = (fgdq & np.uint8(_DQFLAGS["SATURATED"] | _DQFLAGS["DO_NOT_USE"])) != 0
    jump = (fgdq & np.uint8(_DQFLAGS["JUMP_DET"])) != 0
    valid = ~bad[:, :-1] & ~bad[:, 1:] & ~jump[:, 1:]          # (nints, nd, ny, nx)
    nvalid = valid.sum(axis=1, dtype=np.int32)                  # (nints, ny, nx)
    n_jumps = jump.sum(axis=(0, 1), dtype=np.int32)
    if image is None:           # stcal returns None when every ramp starts saturated
        image = {k: np.full((ny, nx), np.nan, _F32)
                 for k in ("slope", "var_rnoise", "var_poisson")}
        integ = {k: np.full((nints, ny, nx), np.nan, _F32)
                 for k in ("slope", "var_rnoise", "var_poisson")}
    slope_dn = np.asarray(image["slope"], dtype=_F32)
    vr_dn = np.asarray(image["var_rnoise"], dtype=_F32)
    vp_dn = np.asarray(image["var_poisson"], dtype=_F32)
    measured = ((nvalid.sum(axis=0) > 0) & np.isfinite(slope_dn) & np.isfinite(vr_dn)
                & np.isfinite(vp_dn))
    slope = np.where(measured, slope_dn * g, _F32(0)).astype(_F32)
    var_read = np.where(measured, vr_dn * g2, _F32(BAD_VARIANCE)).astype(_F32)
    var_pois = np.where(measured, vp_dn * g2, _F32(0)).astype(_F32)
    si = np.asarray(integ["slope"], dtype=_F32)
    vi = (np.asarray(integ["var_rnoise"], dtype=_F32)
          + np.asarray(integ["var_poisson"], dtype=_F32))
    ok_i = (nvalid > 0) & np.isfinite(si) & np.isfinite(vi)
    slope_ints = np.where(ok_i, si * g, _F32(0)).astype(_F32)
    var_ints = np.where(ok_i, vi * g2, _F32(BAD_VARIANCE)).astype(_F32)

    dof = np.where(measured, np.maximum(nvalid.sum(axis=0) - 1, 0), 0).astype(np.int32)
    chi2 = np.zeros((ny, nx), _F32)
    if (dof > 0).any():
        chi2 = model_chi2(e, times, slope, prep.read_noise, valid=valid,
                          resultant_noise=prep.resultant_noise)
        chi2 = np.where(dof > 0, chi2, _F32(0)).astype(_F32)
    dq = np.where(sat.any(axis=(0, 1)), SATURATED, 0).astype(np.uint32)
    dq[n_jumps > 0] |= np.uint32(JUMP_DET)
    dq[~measured] |= np.uint32(DO_NOT_USE)
    dq[prep.refmask] |= np.uint32(REFERENCE_PIXEL | DO_NOT_USE)
    return FitResult(slope=slope, var_read=var_read, var_poisson=var_pois, chi2=chi2,
                     dof=dof, dq=dq, slope_ints=slope_ints, var_ints=var_ints,
                     n_jumps=n_jumps, gain=gain,
                     read_noise=float(np.median(prep.read_noise)),
                     fitter=f"stcal-{alg}")
