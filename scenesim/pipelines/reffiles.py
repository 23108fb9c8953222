"""The calibration references of a simulated detector: what a pipeline needs to undo it.

A pipeline calibrates raw ramps with reference files: the gain, the read noise, the
saturation level, the bias, the nonlinearity, the dark current, a bad-pixel mask and
the IPC kernel.  For a real detector they are measured; for a scenesim detector they
are *known*, since they are the parameters the engine used.  :func:`detector_reference`
collects them, from the scene and its engine, into one :class:`DetectorReference` of
plain arrays (units below); the writers of :mod:`scenesim.pipelines.jwst` (FITS, for
``jwst``'s ``override_*`` step arguments) and :mod:`scenesim.pipelines.roman` (ASDF,
for ``romancal``) only change the layout and the units of these arrays.

What each reference holds, and how it follows from the forward model of
:mod:`scenesim.engine` (charge ``q`` -> saturation at the full well -> nonlinearity
``m = p(q)`` -> IPC -> + bias and noise -> ``DN = rint(e / gain)``):

* **gain** (e-/DN): the ADC gain, one value for every pixel.
* **read noise** (e- per read, not CDS): the white read noise of each pixel's output
  (``rd_noise``, per output if given), times ``ref_ratio`` on reference pixels.  The
  correlated components (1/f, ACN, pedestal) are not in it: a pipeline removes what it
  can of them with the reference pixels.  Pipelines want other conventions (JWST: the
  CDS noise of two frames in DN; romancal: DN per read); the writers convert.
* **bias** (e-): the reset level every integration starts from on average:
  ``bias_offset + bias_amp * template`` (:func:`noise.template.template_for`); kTC
  and pedestal noise have mean 0.  The engine couples only charge through IPC, never
  the bias; a pipeline that undoes IPC *before* it subtracts the bias (JWST: ``ipc``
  then ``superbias``) needs the bias passed through its own IPC correction, which
  its writer does (:mod:`scenesim.pipelines.jwst`).
* **saturation** (e-, bias included, as a raw value): the lowest level the raw
  signal of a full pixel can show, ``bias + k[1, 1] p(full_well)`` (IPC keeps a
  fraction ``k[1, 1]`` of a pixel's own charge; its neighbours only add; the pixel's
  own full well where it is a map), minus a margin of ``SATURATION_MARGIN_SIGMA``
  times the rms spread of every noise component around the bias
  (:meth:`noise.NoiseParams.spread` with the detector: white, kTC, pedestal, ACN,
  picture frame, each 1/f one at its process's whole rms), so that a full pixel is
  flagged whatever its noise draw.  Not the white noise alone: kTC (29 e- in the
  paper), the pedestal and the slow 1/f wander hold for a whole integration, and a
  margin of 5 white sigma left about one saturated pixel in seven below it for its
  whole ramp, fitted as ~0 e-/s with no flag (romancal has no neighbour growth to
  hide it).  A bright pixel just below the full well may be flagged a little early:
  data lost, never a biased slope.  No full well: the ADC's top code.
* **linearity**: the polynomial in DN of bias-subtracted raw signal that returns the
  linear signal, ``q = sum_i a_i m**i``: a least-squares fit of the exact inverse
  (:meth:`Nonlinearity.invert`) on ``m`` in ``[0, p(full_well)]``, of degree
  :data:`LINEARITY_DEGREE`; its largest error over that range is recorded
  (``linearity_error``, e-).  Linear detector: ``[0, 1]``.
* **nonlinearity** (the inverse of the linearity): the engine's own law ``m = p(q)``
  written in DN, ``m_DN = q_DN + c2 g q_DN**2 + c3 g**2 q_DN**3 + ...``, exact (it is
  a polynomial); romancal's linearity step needs it to rebuild the reads of a
  resultant (``InverselinearityRefModel``).  Linear detector: ``[0, 1]``.
* Both polynomials act on *bias-subtracted* DN.  A pipeline that applies them to raw
  DN (romancal has no bias step before ``linearity``) needs them re-centred on each
  pixel's bias: :func:`shift_polynomial` gives the per-pixel coefficients of
  ``x -> P(x - b)``.  The per-integration part of the reset level (kTC, pedestal:
  tens of e-) is not in ``b``; it moves the point where the polynomial is evaluated
  by ``delta``, which changes a linearised slope by the relative amount ``2 a2
  delta`` (``a2`` the quadratic coefficient per DN: 3e-5 for 1.6e-6 /DN and 10 DN).
* **dark** (e-/s): dark current plus hot pixels, the same draws as the run's
  (:func:`scenesim.sky.rates.scene_rates` draws them from the scene seed's
  ``HOT_PIXELS`` stream); 0 on reference pixels.  It is the dark *before* IPC: the
  pipeline subtracts it after undoing IPC.
* **raw level** (e-, ``raw_level``): the mean level of the raw samples that are not
  image pixels (IRS2's interleaved reference samples, the reference output): the
  constant ``bias_offset`` (:mod:`noise.generator`: the templates and kTC are maps
  of the image's pixels, and a reference sample's kTC has mean 0).  A pipeline that
  subtracts a bias from the raw samples (JWST's IRS2 ``superbias``) needs it.
* **mask** (DQ bits, JWST values): ``REFERENCE_PIXEL`` on the reference border,
  ``HOT`` on hot pixels (flagged, still fitted: not ``DO_NOT_USE``).
* **IPC kernel**: the engine's 3x3 kernel, ``k[1 + dy, 1 + dx]`` the fraction of a
  pixel's signal seen by its neighbour at ``(y + dy, x + dx)`` (the identity when
  there is no IPC), and its inverse, truncated to 5x5
  (:func:`ipc_inverse_kernel`): what a pipeline that corrects IPC by convolution
  (JWST's ``ipc`` step) needs.
"""

import math
import os
from dataclasses import dataclass

import numpy as np

from noise.errors import ParameterError
from noise.template import template_for

from scenesim.detector.dq import REFERENCE_PIXEL
from scenesim.sky.maps import load_map
from scenesim.sky.rates import hot_pixel_map

__all__ = ["DetectorReference", "detector_reference", "reference_id",
           "check_reference_id", "linearity_coefficients",
           "nonlinearity_coefficients", "shift_polynomial", "ipc_inverse_kernel", "HOT",
           "LINEARITY_DEGREE", "SATURATION_MARGIN_SIGMA"]

#: JWST DQ bit of a hot pixel (``HOT`` = 2**11 in the JWST DQ definitions).
HOT = 2 ** 11

#: Degree of the linearity-correction polynomial written to the references.
LINEARITY_DEGREE = 6

#: The saturation level is this many times the noise's rms spread below the full-well
#: level (module notes).
SATURATION_MARGIN_SIGMA = 5.0


@dataclass(frozen=True, eq=False)
class DetectorReference:
    """The calibration references of one simulated detector (read-out image shape).

    Attributes
    ----------
    detector : noise.clock.Detector
    gain : float
        e-/DN.
    read_noise : ndarray, shape (ny, nx), float64, e- per read (not CDS)
    bias : ndarray, shape (ny, nx), float64, e-
        Mean reset level (no IPC: the engine does not couple it).
    saturation : ndarray, shape (ny, nx), float64, e- (raw, bias included)
    linearity : ndarray, shape (ncoeffs,), float64
        ``q_DN = sum_i linearity[i] * m_DN**i`` on bias-subtracted DN.
    linearity_error : float
        Largest error of that polynomial on ``[0, p(full_well)]``, e-.
    nonlinearity : ndarray, shape (ncoeffs,), float64
        ``m_DN = sum_i nonlinearity[i] * q_DN**i`` on bias-subtracted DN: the
        engine's law, which ``linearity`` inverts (:func:`nonlinearity_coefficients`).
    dark : ndarray, shape (ny, nx), float64, e-/s
    mask : ndarray, shape (ny, nx), uint32, JWST DQ bits
    ipc_kernel : ndarray, shape (3, 3), float64
    ipc_inverse : ndarray, shape (5, 5), float64
        :func:`ipc_inverse_kernel` of ``ipc_kernel``.
    adc_top : int
        Highest ADC code.
    raw_level : float
        Mean level (e-) of the raw samples that are not image pixels (interleaved
        reference samples, reference output): ``bias_offset``; 0 without noise.
    """

    detector: object
    gain: float
    read_noise: np.ndarray
    bias: np.ndarray
    saturation: np.ndarray
    linearity: np.ndarray
    linearity_error: float
    nonlinearity: np.ndarray
    dark: np.ndarray
    mask: np.ndarray
    ipc_kernel: np.ndarray
    ipc_inverse: np.ndarray
    adc_top: int
    raw_level: float = 0.0

    @property
    def has_ipc(self):
        """True when the kernel is not the identity."""
        return self.ipc_kernel[1, 1] != 1.0


def linearity_coefficients(nonlinearity, full_well, gain, *, degree=LINEARITY_DEGREE):
    """Polynomial that linearises bias-subtracted DN, and its largest error.

    Parameters
    ----------
    nonlinearity : scenesim.detector.nonlinearity.Nonlinearity or None
        ``m = p(q)`` in e-; None (or linear) gives ``[0, 1]``.
    full_well : float
        Largest charge the polynomial must cover, e- (> 0).
    gain : float
        e-/DN.
    degree : int, keyword-only
        Polynomial degree (>= 1).

    Returns
    -------
    coeffs : ndarray, shape (degree + 1,), float64
        ``q/gain = sum_i coeffs[i] * (m/gain)**i`` (DN in, DN out), lowest order first.
    max_error : float
        Largest ``|poly(m) - p^-1(m)|`` over 4097 points of ``[0, p(full_well)]``, e-.
    """
    if nonlinearity is None or nonlinearity.is_linear:
        return np.array([0.0, 1.0]), 0.0
    if not (np.isfinite(full_well) and full_well > 0):
        raise ParameterError(f"'full_well' must be a finite number > 0 (e-) to fit a "
                             f"linearity correction, got {full_well!r}")
    q = np.linspace(0.0, float(full_well), 4097)
    m = nonlinearity.apply(q)
    scale = float(m[-1])
    # fit q(m) on the scaled variable u = m / scale, then rescale to DN
    a = np.polynomial.polynomial.polyfit(m / scale, q, degree)
    err = float(np.max(np.abs(np.polynomial.polynomial.polyval(m / scale, a) - q)))
    m_dn_scale = scale / gain
    coeffs = a / gain / m_dn_scale ** np.arange(degree + 1)
    coeffs[0] = 0.0 if abs(a[0]) < 1e-9 * full_well else coeffs[0]
    return coeffs, err


def nonlinearity_coefficients(nonlinearity, gain):
    """The engine's nonlinearity ``m = p(q)`` as a polynomial in DN.

    Parameters
    ----------
    nonlinearity : scenesim.detector.nonlinearity.Nonlinearity or None
        ``m = q + c2 q**2 + c3 q**3 + ...`` in e-; None (or linear) gives ``[0, 1]``.
    gain : float
        e-/DN (> 0).

    Returns
    -------
    ndarray, shape (ncoeffs,), float64
        ``m/gain = sum_i b[i] (q/gain)**i``, lowest order first: ``b = [0, 1, c2 gain,
        c3 gain**2, ...]`` (substituting ``q = gain q_DN`` and dividing by ``gain``).
    """
    if not (np.isfinite(gain) and gain > 0):
        raise ParameterError(f"'gain' must be a finite number > 0 (e-/DN), got {gain!r}")
    if nonlinearity is None or nonlinearity.is_linear:
        return np.array([0.0, 1.0])
    c = np.asarray(nonlinearity.coeffs, dtype=np.float64)
    return np.concatenate([[0.0, 1.0], c * float(gain) ** np.arange(1, c.size + 1)])


def shift_polynomial(coeffs, offset, *, dtype=np.float64):
    """Coefficients of ``x -> P(x - offset)``, for each offset.

    ``P(x - b) = sum_k a_k (x - b)**k = sum_i x**i sum_{k >= i} a_k C(k, i) (-b)**(k-i)``
    (binomial expansion), computed in float64 one coefficient at a time.

    Parameters
    ----------
    coeffs : array_like, shape (n,)
        ``a_k`` of ``P``, lowest order first.
    offset : array_like, any shape
        ``b`` (the same unit as ``x``; e.g. a per-pixel bias in DN).
    dtype : numpy dtype, keyword-only
        Of the result (float32 for a reference file: the float64 cube of a full
        4096 x 4096 array is never held).

    Returns
    -------
    ndarray, shape (n,) + offset.shape, ``dtype``
        Lowest order first.
    """
    a = np.asarray(coeffs, dtype=np.float64)
    if a.ndim != 1 or a.size == 0 or not np.all(np.isfinite(a)):
        raise ParameterError(f"'coeffs' must be a non-empty 1-D array of finite numbers, "
                             f"got {coeffs!r}")
    b = np.asarray(offset, dtype=np.float64)
    n = a.size
    out = np.empty((n,) + b.shape, dtype=dtype)
    minus_b = -b
    for i in range(n):
        # sum over k >= i of a_k C(k, i) (-b)^(k - i), by Horner in (-b)
        acc = np.zeros(b.shape)
        for k in range(n - 1, i - 1, -1):
            acc = acc * minus_b + a[k] * math.comb(k, i)
        out[i] = acc
    return out


def ipc_inverse_kernel(kernel, *, size=5, grid=64):
    """The convolution kernel that undoes ``kernel``, truncated to ``size`` x ``size``.

    The exact inverse of a 3x3 IPC kernel has infinite support; its values fall as
    ``alpha**d`` at distance ``d``, so a 5x5 truncation leaves errors of order
    ``alpha**3`` (3e-6 for 1.5 % coupling).  Computed as ``IFFT(1 / FFT(k))`` on a
    periodic ``grid`` x ``grid`` torus (far larger than the support), cropped
    around the centre and renormalised to sum 1 (a flat signal is unchanged), in the
    same orientation as ``kernel`` (both act by convolution).

    Parameters
    ----------
    kernel : ndarray, shape (3, 3)
    size : int, keyword-only
        Odd output size.
    grid : int, keyword-only

    Returns
    -------
    ndarray, shape (size, size), float64
    """
    k = np.asarray(kernel, dtype=np.float64)
    pad = np.zeros((grid, grid))
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            pad[dy % grid, dx % grid] = k[1 + dy, 1 + dx]
    inv = np.real(np.fft.ifft2(1.0 / np.fft.fft2(pad)))
    h = size // 2
    out = np.empty((size, size))
    for dy in range(-h, h + 1):
        for dx in range(-h, h + 1):
            out[h + dy, h + dx] = inv[dy % grid, dx % grid]
    return out / out.sum()


def _dark_rate(scene):
    """Dark current plus hot pixels (e-/s), the draws of :func:`scene_rates`, and the
    hot-pixel mask."""
    det, src = scene.detector, scene.sources
    refmask = det.reference_mask()
    dark = np.array(np.broadcast_to(load_map(src.dark_current, det, name="dark_current"),
                                    det.shape), dtype=np.float64)
    hot = np.zeros(det.shape, dtype=bool)
    if src.hot_pixel_fraction > 0:
        extra = hot_pixel_map(src, det, scene.seed, refmask)
        dark = dark + extra
        hot = extra > 0
    dark[refmask] = 0.0
    return dark, hot


def detector_reference(scene, engine):
    """The calibration references of the detector ``engine`` simulates for ``scene``.

    Parameters
    ----------
    scene : scenesim.scene.Scene
        With its seed set (the hot pixels are drawn from it, as in the run).
    engine : scenesim.engine.ChargeEngine
        Built from ``scene`` (:func:`scenesim.run.build_engine`).

    Returns
    -------
    DetectorReference
    """
    if scene.seed is None:
        raise ParameterError("'scene' must have its seed set (scene.ensure_seed()) to "
                             "rebuild its hot pixels")
    det = engine.detector
    gain = float(engine.gain)
    top = int(2 ** engine.adc_bits - 1)
    refmask = det.reference_mask()
    params = engine.noise.params if engine.noise is not None else None
    if params is not None and params.enabled("rd_noise"):
        rd = params.per_output("rd_noise", det.n_out_active)[det.output_of_column()]
        read_noise = np.broadcast_to(np.asarray(rd, dtype=np.float64), det.shape).copy()
        read_noise[refmask] *= float(params.ref_ratio)
    else:
        read_noise = np.zeros(det.shape)
    bias = np.zeros(det.shape)
    if params is not None:
        if params.bias_amp > 0:
            bias += float(params.bias_amp) * template_for(det, params.pca0_file)
        bias += float(params.bias_offset)
    kernel = np.zeros((3, 3))
    kernel[1, 1] = 1.0
    if engine.ipc_kernel is not None:
        kernel = np.asarray(engine.ipc_kernel, dtype=np.float64)
        kernel = kernel / kernel.sum()
    nl = engine.nonlinearity
    if engine.full_well is not None:
        fw = float(engine.full_well.max)
        own = np.asarray(engine.full_well.value, dtype=np.float64)
        level = own if nl is None else nl.apply(own)
        spread = 0.0 if params is None else params.spread(det)
        saturation = bias + kernel[1, 1] * level - SATURATION_MARGIN_SIGMA * spread
        saturation = np.minimum(saturation, top * gain)
    else:
        fw = top * gain
        saturation = np.full(det.shape, top * gain)
    coeffs, err = linearity_coefficients(nl, fw, gain)
    dark, hot = _dark_rate(scene)
    mask = np.zeros(det.shape, dtype=np.uint32)
    mask[refmask] |= np.uint32(REFERENCE_PIXEL)
    mask[hot] |= np.uint32(HOT)
    return DetectorReference(detector=det, gain=gain, read_noise=read_noise, bias=bias,
                             saturation=saturation, linearity=coeffs,
                             linearity_error=err,
                             nonlinearity=nonlinearity_coefficients(nl, gain),
                             dark=dark, mask=mask,
                             ipc_kernel=kernel, ipc_inverse=ipc_inverse_kernel(kernel),
                             adc_top=top,
                             raw_level=0.0 if params is None else float(params.bias_offset))


def reference_id(reference):
    """A 16-hex-digit digest of everything a :class:`DetectorReference` holds.

    Written into the references (JWST: primary card ``SSREFID``; Roman:
    ``meta.scenesim_refid``) and into the uncal or L1 of the same run, so that the
    pipeline commands refuse references of another run: the same detector and size,
    but other hot pixels, dark or bias (a probe's pair of runs differed in 93 hot
    pixels and moved 93 rates by up to 195 e-/s, which compare could not see: it
    takes the dark reference's own rate out of the truth).  Runs whose references
    are the same (no hot pixels, another seed) share it."""
    import hashlib
    h = hashlib.sha256()
    for a in (reference.gain, reference.read_noise, reference.bias, reference.saturation,
              reference.linearity, reference.nonlinearity, reference.dark,
              reference.mask, reference.ipc_kernel, reference.adc_top,
              reference.raw_level):
        v = np.ascontiguousarray(a)
        h.update(str((v.dtype.str, v.shape)).encode())
        h.update(v.tobytes())
    return h.hexdigest()[:16]


def check_reference_id(reftype, ref, ref_id, kind, data, data_id):
    """Raise unless a reference's :func:`reference_id` (``ref_id``) is the one the
    pipeline input ``data`` (its ``kind``: 'uncal', 'L1') recorded (``data_id``);
    files without one (written otherwise, or before) are not checked."""
    if ref_id is None or data_id is None or str(ref_id) == str(data_id):
        return
    raise ParameterError(
        f"{reftype} reference {os.fspath(ref)!r} describes another run's detector "
        f"(reference id {ref_id}) than the {kind} {os.fspath(data)!r} was simulated "
        f"with ({data_id}): their hot pixels, dark, bias or saturation differ; use "
        f"the references written with it ('scenesim run SCENE --reffiles')")
