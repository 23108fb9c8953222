"""Noise amplitudes and their definitions (Rauscher 2015, Table 1, made length-independent).

Units are electrons.  Read noise is **per read** (one frame), not CDS: the CDS noise of
white read noise alone is ``sqrt(2) * rd_noise``.

Amplitude definition
--------------------
Every 1/f component (``c_pink``, ``u_pink``, ``acn``, ``pca0``) is a stationary Gaussian
process with a fixed power spectral density (PSD).  Its amplitude is the **expected
standard deviation of the component over one frame's time line** (one output, overhead
samples included, the frame mean removed)::

    amp**2 = integral_0^f_nyq  S(f) * (1 - F_n(f)) df

where ``S`` is the one-sided PSD and ``F_n`` the Fejer kernel of an ``n``-sample mean
(``n`` = samples per frame of that series).  The PSD level therefore does not depend on
how many frames are simulated: a 1-frame and a 100-frame cube share the same PSD.  In
the original NG program each realisation was rescaled to a sample sigma over the whole
cube, so its PSD level fell as the cube grew.  With this definition the paper's default
amplitudes reproduce a NIRSpec-like single frame, as they did in the original for a
1-frame cube.  ACN's ``n`` is that of each of its two parity series (even and odd
columns, each normalised on its own), so the frame's ACN image, whose two parities
also differ in their means, has a larger spread than ``acn`` (0.59-0.89 e- for
``acn = 0.5`` on 37 ms frames).  Over many frames each 1/f process also wanders
below one frame (``NoiseParams.check_adc`` counts that).

``pedestal`` is the standard deviation of a per-frame offset common to all pixels;
``ktc`` the per-pixel standard deviation of the reset level, redrawn each integration;
``bias_offset`` a constant reset level; ``bias_amp`` multiplies the picture-frame
template (zero median, unit *robust* sigma; far from Gaussian: the synthetic one
spans -0.82 to +13.7 on a full H2RG, standard deviation 3.2) to make the fixed bias
pattern (as the original did).

Beyond the paper: random telegraph noise (``rtn_fraction`` of regular pixels switch
between two levels ``rtn_amp`` apart, with mean dwell times ``rtn_tau_low`` and
``rtn_tau_high`` in seconds), a user PSD shape for the pink components
(``pink_spectrum``: pairs of frequency in Hz and relative PSD, interpolated in log-log;
the amplitude definition above still sets the level), per-output amplitudes for
``rd_noise``, ``u_pink`` and ``acn`` (a sequence of ``n_out`` values).

Limits
------
Frames are float32 (largest value 3.4e38), so every amplitude, ``|bias_offset|`` and
the reference-pixel noise ``rd_noise * ref_ratio`` must be at most
:data:`MAX_AMPLITUDE` = 1e30 e-: the sum of every component, tails included, then stays
far inside the float32 range (it used to overflow to inf with a RuntimeWarning, e.g.
``c_pink = 1e300``).  Two limits need more than the amplitudes, and are checked where
that is known:

* :meth:`NoiseParams.check_detector` (the noise generator, a scene): ``f_min`` must be
  below the Nyquist frequency of every 1/f series it shapes (``1 / (2 dt)`` for the
  pink series, ``1 / (4 dt)`` for ACN, ``1 / (2 row time)`` for picture-frame noise);
* :meth:`NoiseParams.check_adc` (a scene, the engine, a DN noise file: where the
  gain, the ADC bits and the detector are known): the reset level of a pixel without
  charge is ``bias_offset``, plus the fixed bias pattern ``bias_amp`` times the
  template, plus the other components, whose rms spread ``s`` is the root sum of
  squares of every amplitude that reaches every pixel (all but ``rtn_amp``; the white
  noise at the larger of the regular and reference-pixel levels,
  :meth:`NoiseParams.spread`).  On the detector, each 1/f amplitude (defined within
  one frame, mean removed) counts at its process's whole rms, which also wanders
  below one frame (x1.2 on a full H2RG frame, x1.7-1.9 on 18 ms frames at ``f_min =
  1e-4``), picture-frame noise at the template's largest value, and the bias pattern,
  deterministic and far from Gaussian (the synthetic template spans -0.82 to +13.7
  robust sigmas on a full H2RG), by its extremes ``[b_lo, b_hi]``
  (:meth:`NoiseParams.bias_pattern_range`).  The ADC clips below code 0 and above
  its top code, ``gain * (2**bits - 1)`` e-, so ``bias_offset`` must lie in ``[5 s -
  b_lo, range - 5 s - b_hi]`` (:data:`BIAS_SPREAD_SIGMA` = 5): then at most 2.9e-7
  of a Gaussian component's values clip on each side, at the pattern's extreme
  pixel.  Outside it the ADC silently flattens the noise a user asked for: e.g.
  ``preset = "none"`` (``bias_offset = 0``) with ``rd_noise = 5`` put half of every
  dark pixel's reads at code 0, and (before the pattern and the 1/f wander were
  counted so) a 256 x 256 H2RG with ``bias_offset = 62000`` read 9.7 % of its reads
  at the top code.  When ``10 s + b_hi - b_lo`` exceeds the range no bias fits, and
  the error names the largest amplitude instead.  Charge, which only adds, is not
  counted: reaching the top code is saturation (the truth's ``SATREAD``).  Two more
  ends: the RTN pixels' high state, ``bias_offset + b_hi + rtn_amp``, must also lie 5
  s below the top code (when there are RTN pixels), and half an ADC step (``gain /
  2``) may not exceed ``bias_offset + b_hi + 5 s``, where every read of a pixel
  without charge would round to code 0.  Without a detector, or on a full array over
  :data:`TEMPLATE_CHECK_PIXELS`, the amplitudes are taken as they are and the bias
  pattern as a Gaussian of rms ``bias_amp``.

The 1/f synthesis bounds two options: ``f_min >= 1e-20`` Hz (:data:`MIN_F_MIN`; a
flat PSD below a period of 3e12 years; lower values need hundreds of filter bands and
overflow the PSD table near 1e-300), and ``pink_spectrum`` PSD values in ``[1e-30,
1e30]`` (:data:`PSD_RANGE`; its filters are float32, which 1e300 overflows and a
uniform 1e-300 turns into an overflowing scale; only the shape matters, so rescale
the values).
"""

import dataclasses
import math
import os
import warnings
from dataclasses import dataclass

import numpy as np

from noise.validate import check_float, describe, is_real, is_sequence
from noise.errors import ParameterError, ParameterTypeError, ScenesimWarning

__all__ = ["NoiseParams", "NIRSPEC_DEFAULTS", "ZERO_NOISE", "MAX_AMPLITUDE",
           "BIAS_SPREAD_SIGMA", "TEMPLATE_CHECK_PIXELS", "MIN_F_MIN", "PSD_RANGE",
           "check_pink_spectrum"]

#: Largest amplitude (and ``|bias_offset|``, ``rd_noise * ref_ratio``), e-: float32
#: frames stay finite (module notes).
MAX_AMPLITUDE = 1e30
#: ``bias_offset`` must lie this many rms spreads of the other components inside
#: the ADC range (module notes, :meth:`NoiseParams.check_adc`).
BIAS_SPREAD_SIGMA = 5.0
#: Largest full array (pixels) whose template :meth:`NoiseParams.check_adc` measures
#: (16384^2, four times an H4RG): its statistics take ~0.1 s at 4096^2 and grow with
#: the size, and a scene's checks run before its size budget refuses an array too
#: large for the machine (``naxis = 400000``: 3 s); beyond it the bias pattern is
#: taken for a Gaussian of rms ``bias_amp`` (module notes).
TEMPLATE_CHECK_PIXELS = 2 ** 28
#: Smallest ``f_min``, Hz (module notes).
MIN_F_MIN = 1e-20
#: ``pink_spectrum`` PSD values lie in ``[1 / PSD_RANGE, PSD_RANGE]`` (module notes).
PSD_RANGE = 1e30

_PER_OUTPUT = ("rd_noise", "u_pink", "acn")
_SCALAR_AMPS = ("c_pink", "pca0", "pedestal", "ktc", "bias_amp", "rtn_amp")
#: Fields that shape a component but add nothing by themselves; every other field is
#: an amplitude (e-), so a new component's amplitude is known to :meth:`is_silent`.
_OPTIONS = ("ref_ratio", "rtn_fraction", "rtn_tau_low", "rtn_tau_high", "f_min",
            "pink_spectrum", "pca0_file")


def _freeze(name, value):
    """A per-output amplitude as a float or a tuple of floats (checked types)."""
    if isinstance(value, (list, tuple, np.ndarray)):
        if isinstance(value, np.ndarray) and value.ndim > 1:     # not flattened
            raise ParameterTypeError(
                f"{name!r} must be a number or a 1-D sequence of numbers (one per "
                f"output, e-), got an array of shape {value.shape}")
        items = list(np.ravel(value)) if isinstance(value, np.ndarray) else list(value)
        if not items or not all(is_real(v) for v in items):
            raise ParameterTypeError(
                f"{name!r} must be a number or a non-empty sequence of numbers (one per "
                f"output, e-), got {describe(value)}")
        return tuple(float(v) for v in items)
    return value


def check_pink_spectrum(name, value):
    """``value`` as a tuple of ``(f_Hz, psd)`` float pairs: at least two, frequencies
    finite, > 0 and strictly increasing, PSD values finite and > 0."""
    if isinstance(value, (str, bytes, dict)) or not is_sequence(value) or not all(
            is_sequence(pair) and len(pair) == 2 and all(is_real(v) for v in pair)
            for pair in value):
        raise ParameterTypeError(
            f"{name!r} must be a sequence of (f_Hz, psd) pairs of numbers, got "
            f"{describe(value)}")
    spec = np.asarray(value, dtype=float).reshape(-1, 2)
    if spec.shape[0] < 2:
        raise ParameterError(
            f"{name!r} must be a sequence of at least two (f_Hz, psd) pairs, got "
            f"{spec.shape[0]}")
    if (not np.all(np.isfinite(spec)) or np.any(spec[:, 0] <= 0)
            or np.any(spec[:, 1] <= 0) or np.any(np.diff(spec[:, 0]) <= 0)):
        raise ParameterError(
            f"{name!r} needs finite frequencies > 0, strictly increasing, and PSD "
            f"values > 0, got {describe(value)}")
    if np.any(spec[:, 1] < 1.0 / PSD_RANGE) or np.any(spec[:, 1] > PSD_RANGE):
        raise ParameterError(
            f"{name!r} PSD values must lie in [{1.0 / PSD_RANGE:g}, {PSD_RANGE:g}] (a "
            f"relative shape: rescale them), got {describe(value)}")
    return tuple((float(f), float(p)) for f, p in spec)


@dataclass(frozen=True)
class NoiseParams:
    """Noise amplitudes (e-) and options for :class:`noise.NoiseGenerator`.

    Parameters
    ----------
    rd_noise : float or sequence of float
        White read noise per read of a regular pixel, e- rms (per output if a sequence).
    ref_ratio : float
        Ratio of reference-pixel to regular-pixel white noise.
    c_pink : float
        Correlated 1/f noise, shared by all outputs, e- (see amplitude definition).
    u_pink : float or sequence of float
        Uncorrelated 1/f noise, independent per output, e-.
    acn : float or sequence of float
        Alternating column noise: independent 1/f series on even and odd columns, e-.
    pca0 : float
        Picture-frame noise: template times a 1/f series sampled once per row, e-.
    pedestal : float
        Per-frame offset common to all pixels, e- rms.
    ktc : float
        kTC reset noise per pixel per integration, e- rms.
    bias_offset : float
        Constant reset level, e-.
    bias_amp : float
        Amplitude of the fixed bias pattern (template times this), e-.
    rtn_fraction : float
        Fraction of regular pixels with random telegraph noise, in [0, 1].
    rtn_amp : float
        Step between the two RTN levels, e-.
    rtn_tau_low, rtn_tau_high : float
        Mean dwell times in the low and high states, s.
    f_min : float
        Frequency (Hz) below which the 1/f PSD is flat (keeps the process stationary).
    pink_spectrum : tuple of (float, float) pairs or None
        User PSD shape ``((f_Hz, psd), ...)`` replacing 1/f for all pink components.
    pca0_file : str or None
        FITS file with the picture-frame / bias template (full array, or the read-out
        size); ``None`` uses the synthetic template shipped with the package.
    """

    rd_noise: float | tuple = 5.2
    ref_ratio: float = 0.8
    c_pink: float = 3.0
    u_pink: float | tuple = 1.0
    acn: float | tuple = 0.5
    pca0: float = 0.2
    pedestal: float = 4.0
    ktc: float = 29.0
    bias_offset: float = 5000.0
    bias_amp: float = 500.0
    rtn_fraction: float = 0.0
    rtn_amp: float = 20.0
    rtn_tau_low: float = 1.0
    rtn_tau_high: float = 0.3
    f_min: float = 1e-4
    pink_spectrum: tuple | None = None
    pca0_file: str | None = None

    def __post_init__(self):
        for name in _PER_OUTPUT:
            object.__setattr__(self, name, _freeze(name, getattr(self, name)))
        for name in _PER_OUTPUT:
            value = getattr(self, name)
            if isinstance(value, tuple):
                for v in value:
                    if not math.isfinite(v) or v < 0:
                        raise ParameterError(
                            f"{name!r} must be finite and >= 0 (e-), got {value!r}")
            else:      # stored as a Python float (a float16 would compute in float16)
                object.__setattr__(self, name, check_float(name, value, minimum=0.0))
        for name in _SCALAR_AMPS + ("ref_ratio",):
            object.__setattr__(self, name, check_float(name, getattr(self, name),
                                                       minimum=0.0))
        object.__setattr__(self, "bias_offset", check_float("bias_offset",
                                                            self.bias_offset))
        for name in _PER_OUTPUT + _SCALAR_AMPS + ("bias_offset",):
            if max(abs(v) for v in self._values(name)) > MAX_AMPLITUDE:
                raise ParameterError(
                    f"{name!r} = {getattr(self, name)!r} e- is beyond what float32 frames "
                    f"hold: amplitudes (and |bias_offset|) must be <= {MAX_AMPLITUDE:g} e-")
        for name, kw in (("rtn_fraction", dict(minimum=0.0, maximum=1.0)),
                         ("rtn_tau_low", dict(minimum=0.0, strict_min=True)),
                         ("rtn_tau_high", dict(minimum=0.0, strict_min=True)),
                         ("f_min", dict(minimum=MIN_F_MIN))):
            object.__setattr__(self, name, check_float(name, getattr(self, name), **kw))
        ref_noise = max(self._values("rd_noise")) * self.ref_ratio
        if ref_noise > MAX_AMPLITUDE:
            raise ParameterError(
                f"'ref_ratio' x 'rd_noise' (the reference pixels' white noise) must be "
                f"<= {MAX_AMPLITUDE:g} e- (float32 frames), got {self.ref_ratio!r} x "
                f"{max(self._values('rd_noise'))!r} = {ref_noise:g}")
        if self.pink_spectrum is not None:
            object.__setattr__(self, "pink_spectrum",
                               check_pink_spectrum("pink_spectrum", self.pink_spectrum))
        if isinstance(self.pca0_file, os.PathLike):       # as every other path argument
            object.__setattr__(self, "pca0_file", os.fspath(self.pca0_file))
        if self.pca0_file is not None and not isinstance(self.pca0_file, str):
            raise ParameterTypeError(
                f"'pca0_file' must be a path string or None, got {describe(self.pca0_file)}")

    def _values(self, name):
        value = getattr(self, name)
        return value if isinstance(value, tuple) else (value,)

    def nyquist_limits(self, detector):
        """``{component: Nyquist frequency (Hz)}`` of the 1/f series that ``f_min``
        shapes on ``detector``, for the enabled components (empty when none is)."""
        out = {}
        if self.c_pink > 0 or self.enabled("u_pink"):
            out["pink"] = 0.5 / detector.dt
        if self.enabled("acn"):
            out["acn"] = 0.25 / detector.dt
        if self.pca0 > 0:
            out["pca0"] = 0.5 / detector.row_time
        return out

    def check_detector(self, detector, *, where="the detector's"):
        """Raise :class:`~noise.errors.ParameterError` if these amplitudes cannot be
        generated on ``detector``: per-output values that do not match its active
        outputs, ``f_min`` not below the Nyquist frequency of an enabled 1/f series
        (module notes), or ACN on an odd number of columns per output or an odd row
        length.  ``where`` names the detector's keys in the message (a scene
        passes ``'[detector]'``)."""
        n_out = detector.n_out_active
        for name in _PER_OUTPUT:
            value = getattr(self, name)
            if isinstance(value, tuple) and len(value) != n_out and not (
                    n_out != detector.n_out and len(value) == detector.n_out):
                also = (f" (a window: or the full array's {detector.n_out}, of which "
                        f"it takes its output's)" if n_out != detector.n_out else "")
                raise ParameterError(
                    f"{name!r} has {len(value)} per-output values but the detector "
                    f"reads through {n_out} outputs{also}")
        il = getattr(detector, "interleave", None)
        extra, values = "", f"'nroh' = {detector.nroh}"
        if il is not None:
            # interleaved reference samples take pixel times in every row
            extra = (" + ('interleave.reference' + 2 'interleave.jump') per "
                     "'interleave.normal' columns")
            values += (f", 'interleave.normal' = {il.normal}, 'interleave.reference' = "
                       f"{il.reference}, 'interleave.jump' = {il.jump}")
        how = {"pink": "1 / (2 'dt')", "acn": "1 / (4 'dt')",
               "pca0": f"1 / (2 row time), row time = (columns per output{extra} + "
                       f"'nroh') x 'dt'"}
        for comp, nyq in self.nyquist_limits(detector).items():
            if self.f_min >= nyq:
                raise ParameterError(
                    f"'f_min' = {self.f_min!r} Hz must be below the Nyquist frequency "
                    f"of the {comp} series, {how[comp]} = {nyq:.6g} Hz with {where} "
                    f"'dt' = {detector.dt!r} s and {values}")
        if self.enabled("acn"):           # even and odd columns: two series per output
            if detector.ncols_out % 2:
                raise ParameterError(
                    f"ACN needs an even number of columns per output; got "
                    f"{detector.ncols_out} columns per output ({detector.nx} columns / "
                    f"{n_out} outputs); set 'acn' to 0 or change 'naxis1'/'n_out'/the "
                    f"subarray")
            if detector.row_samples % 2:
                raise ParameterError(
                    f"ACN needs an even row length (columns per output + 'nroh'); got "
                    f"{detector.ncols_out} + {detector.nroh}; make 'nroh' even or set "
                    f"'acn' to 0")

    def check_adc(self, gain, adc_bits, detector=None):
        """Raise :class:`~noise.errors.ParameterError` if an ADC of ``gain`` e-/DN and
        ``adc_bits`` bits would clip the noise of a pixel without charge (module
        notes): ``bias_offset`` must lie in ``[5 s - b_lo, range - 5 s - b_hi]`` e-,
        ``s`` the components' rms spread (:meth:`spread`), ``[b_lo, b_hi]`` the bias
        pattern's extremes (:meth:`bias_pattern_range`; with no ``detector`` the
        pattern counts as one more Gaussian term of ``s`` and ``b_lo = b_hi = 0``),
        ``range = gain * (2**adc_bits - 1)``.  The error names ``bias_offset``, or
        the largest amplitude when ``10 s + b_hi - b_lo`` exceeds the range (no bias
        fits), or ``rtn_amp`` when the RTN pixels' high state, ``bias_offset + b_hi
        + rtn_amp``, is not 5 s below the top code, or ``gain`` when half an ADC
        step exceeds ``bias_offset + b_hi + 5 s`` (every read without charge would
        round to code 0; a noise-free detector with no bias, ``bias_offset + 5 s =
        0``, takes any gain)."""
        top = 2 ** int(adc_bits) - 1
        adc_range = float(gain) * top
        adc = (f"the ADC range [0, {adc_range:.6g}] e- ('gain' {float(gain):g} e-/DN x "
               f"{top} DN of 'adc_bits' {int(adc_bits)})")
        if detector is not None:
            self.check_detector(detector)
            if detector.naxis1 * detector.naxis2 > TEMPLATE_CHECK_PIXELS:
                detector = None              # module notes: the pattern as a Gaussian
        spread = self.spread(detector)
        b_lo, b_hi = (0.0, 0.0) if detector is None else self.bias_pattern_range(detector)
        pattern = ""
        if b_hi > b_lo:
            pattern = (f" and the bias pattern's extremes ('bias_amp' x the template) "
                       f"[{b_lo:.6g}, {b_hi:.6g}] e-")
        how = ("root sum of squares of the amplitudes" if detector is None else
               "root sum of squares of the amplitudes, each 1/f one at its process's "
               "whole rms")
        k = BIAS_SPREAD_SIGMA
        if 2 * k * spread + (b_hi - b_lo) > adc_range:
            name, value = self._largest_amplitude(detector)
            if b_hi - b_lo > 2 * k * spread:
                name, value = "bias_amp", b_hi - b_lo
            who = f"{name!r} = {getattr(self, name)!r} e-"
            if name == "rd_noise" and self.ref_ratio > 1:
                who = (f"'ref_ratio' x 'rd_noise' = {self.ref_ratio!r} x "
                       f"{getattr(self, name)!r} e- (the reference pixels' white noise)")
            room = adc_range - (b_hi - b_lo)
            need = (f"i.e. s <= {room / (2 * k):.6g} e-" if room > 0 else
                    f"but the pattern alone spans {b_hi - b_lo:.6g} e-")
            raise ParameterError(
                f"{who} is too large for the ADC: the "
                f"noise's rms spread s = {spread:.6g} e- ({how}){pattern} must fit "
                f"in {adc} with {k:g} s to spare on each side, {need}, or the ADC "
                f"clips it ({name!r} is the largest term, {value:.6g} e-)")
        dark_top = self.bias_offset + b_hi + k * spread
        if 0 < dark_top < float(gain) / 2:
            raise ParameterError(
                f"'gain' = {float(gain):g} e-/DN is coarser than the reads of a pixel "
                f"without charge: 'bias_offset' {self.bias_offset!r} e-"
                f"{pattern and ' + the bias pattern'} + {k:g} x the "
                f"noise's rms spread s = {spread:.6g} e- is {dark_top:.6g} e-, less than "
                f"half an ADC step, so every such read rounds to code 0; 'gain' must be "
                f"<= {2 * dark_top:.6g} e-/DN")
        lo, hi = k * spread - b_lo, adc_range - k * spread - b_hi
        if not lo <= self.bias_offset <= hi:
            below = self.bias_offset < lo
            z = ((self.bias_offset + b_lo if below else adc_range - self.bias_offset - b_hi)
                 / spread) if spread > 0 else -math.inf
            frac = 0.5 * math.erfc(z / math.sqrt(2.0))
            where = "below code 0" if below else "above the ADC's top code"
            pixel = "a pixel without charge"
            if b_hi > b_lo:
                pixel = (f"the pixel without charge where the bias pattern is "
                         f"{'lowest' if below else 'highest'}")
            raise ParameterError(
                f"'bias_offset' = {self.bias_offset!r} e- puts {100 * frac:.3g} % of the reads "
                f"of {pixel} {where}, where the ADC clips them: with "
                f"the noise's rms spread s = {spread:.6g} e- ({how}){pattern} it must "
                f"lie {k:g} s inside {adc}, i.e. in [{lo:.6g}, {hi:.6g}] e-")
        rtn_top = self.bias_offset + b_hi + self.rtn_amp + k * spread
        if self.rtn_fraction > 0 and rtn_top > adc_range:
            raise ParameterError(
                f"'rtn_amp' = {self.rtn_amp!r} e- puts the high state of the RTN pixels "
                f"('rtn_fraction' {self.rtn_fraction!r}) above the ADC's top code, where "
                f"it clips: 'bias_offset' {self.bias_offset!r}"
                f"{pattern and ' + the bias pattern'} + 'rtn_amp' + {k:g} x the "
                f"noise's rms spread s = {spread:.6g} e- is {rtn_top:.6g} e-, beyond "
                f"{adc}; 'rtn_amp' must be <= "
                f"{adc_range - self.bias_offset - b_hi - k * spread:.6g} e-")

    def warn_quantisation(self, gain, name="'gain'"):
        """Warn (:class:`~noise.errors.ScenesimWarning`) when the ADC's rounding
        swamps the read noise asked for: the smallest white read noise per read is
        above 0 and below half an ADC step (``gain / 2`` e-), so the rounding's own
        ``gain / sqrt(12)`` rms is over 0.58 of it and reads of a dark pixel often
        repeat one code (a probe: ``--unit DN --gain 1000`` wrote one code for every
        read, without a word).  A noise-free detector (``rd_noise`` 0) is not
        warned about."""
        rd = float(np.min(np.asarray(self.rd_noise, dtype=float)))
        gain = float(gain)
        if 0 < rd < gain / 2:
            warnings.warn(
                f"{name} {gain:g} e-/DN: half an ADC step ({gain / 2:g} e-) "
                f"exceeds the white read noise per read ('rd_noise' {rd:g} e-), so "
                f"the rounding ({gain / math.sqrt(12):.3g} e- rms) is "
                f"{gain / math.sqrt(12) / rd:.2g} of that noise and reads of a dark "
                f"pixel often repeat one code; a gain below {2 * rd:g} e-/DN keeps "
                f"the rounding under 0.58 of it", ScenesimWarning,
                stacklevel=3)

    def warn_precision(self, detector):
        """Warn (:class:`~noise.errors.ScenesimWarning`) when the frames' float32
        cannot hold the white read noise on top of the levels they carry: the
        largest level, ``|bias_offset|`` plus the bias pattern's extreme plus 5 rms
        of the rest (:meth:`spread`), has float32 steps over 0.35 of the smallest
        white read noise per read, so the rounding (``step / sqrt(12)``) adds over
        1 % to its variance (a probe: ``bias_offset`` 1e8 e- made 5.2 e- of read
        noise 8.1, 1e9 made it 0, without a word).  Nothing for a noise-free
        detector or an ADC, whose levels :meth:`check_adc` bounds."""
        rd = float(np.min(np.asarray(self.rd_noise, dtype=float)))
        if rd <= 0:
            return
        b_lo, b_hi = self.bias_pattern_range(detector)
        level = abs(self.bias_offset) + max(abs(b_lo), abs(b_hi)) \
            + BIAS_SPREAD_SIGMA * self.spread(detector)
        step = float(np.spacing(np.float32(min(level, 3e38))))
        if step > 0.35 * rd:
            warnings.warn(
                f"float32 frames: the levels reach {level:.4g} e- ('bias_offset' "
                f"{self.bias_offset:g} e-, the bias pattern and 5 x the noise's rms), "
                f"where float32 steps by {step:.3g} e-, over 0.35 of the white read "
                f"noise per read ('rd_noise' {rd:g} e-): the rounding adds "
                f"{step * step / 12 / (rd * rd):.2g} of its variance; keep the levels "
                f"below {2 ** 24 * 0.35 * rd / 2:.4g} e-", ScenesimWarning,
                stacklevel=3)

    def bias_pattern_range(self, detector):
        """``(lo, hi)``, e-: the least and largest value of the fixed bias pattern,
        ``bias_amp`` times the template (:func:`noise.template.template_for`, from
        ``pca0_file`` or the synthetic one) over ``detector``'s read-out image.  The
        template has unit *robust* sigma but is far from Gaussian: the synthetic
        one spans -0.82 to +13.7 on a full H2RG, to +22 on small windows, so its
        extremes, not a sigma, bound the reads (module notes)."""
        if self.bias_amp == 0:
            return 0.0, 0.0
        from noise.template import template_range
        lo, hi = template_range(detector, self.pca0_file)
        return self.bias_amp * lo, self.bias_amp * hi

    def _largest_amplitude(self, detector=None):
        """(name, e-) of the largest term of :meth:`spread`."""
        terms = {name: value for name, value in self._spread_terms(detector)}
        name = max(terms, key=terms.get)
        return name, terms[name]

    def _spread_terms(self, detector=None):
        scale = {} if detector is None else self._process_scales(detector)
        for f in dataclasses.fields(self):
            if f.name in _OPTIONS or f.name in ("rtn_amp", "bias_offset"):
                continue
            if detector is not None and f.name == "bias_amp":
                continue                         # its extremes: bias_pattern_range
            value = max(abs(v) for v in self._values(f.name))
            if f.name == "rd_noise":
                value *= max(1.0, float(self.ref_ratio))
            yield f.name, float(value) * scale.get(f.name, 1.0)

    def _process_scales(self, detector):
        """Per 1/f component, the ratio of its process's whole rms to the amplitude
        (defined within one frame, mean removed): a pixel's reads also wander with
        the frequencies below one frame, 1.2x on a full H2RG frame and 1.7x on 18 ms
        frames at ``f_min = 1e-4`` Hz (more at lower ``f_min``).  Picture-frame noise
        also takes the template's largest ``|value|``, by which it multiplies."""
        from noise.pink import _unit_frame_variance, _unit_total_variance
        det, fm, sp = detector, self.f_min, self.pink_spectrum

        def ratio(rate, n):
            return math.sqrt(_unit_total_variance(rate, fm, sp)
                             / _unit_frame_variance(rate, int(n), fm, sp))
        out = {}
        if self.enabled("c_pink") or self.enabled("u_pink"):
            out["c_pink"] = out["u_pink"] = ratio(1 / det.dt, det.frame_samples)
        if self.enabled("acn"):
            out["acn"] = ratio(0.5 / det.dt, det.frame_samples // 2)
        if self.pca0 > 0:
            from noise.template import template_range
            lo, hi = template_range(det, self.pca0_file)
            out["pca0"] = ratio(1 / det.row_time, det.ny + det.nfoh) * max(-lo, hi)
        return out

    def spread(self, detector=None):
        """Rms spread (e-) of the components around the mean reset level
        ``bias_offset``: the root sum of squares of every amplitude that reaches
        every pixel (the largest per-output value; the white noise at the larger of
        the regular and reference-pixel levels), ``rtn_amp`` left out.  With
        ``detector``, each 1/f amplitude is taken at its process's whole rms and
        picture-frame noise at the template's largest value
        (:meth:`_process_scales`), and the bias pattern, deterministic, is left to
        :meth:`bias_pattern_range`."""
        return math.sqrt(sum(v * v for _, v in self._spread_terms(detector)))

    def for_detector(self, detector):
        """These amplitudes as ``detector`` reads them.  A window reads through one
        output: a per-output value given for the full array (``n_out`` values, as for
        its full frame) becomes the value of the full-array output the window lies
        on, so one noise table describes a detector's full frame and its windows (a
        probe: such a table was refused on every window).

        Raises
        ------
        noise.errors.ParameterError
            A window across two full-array outputs given full-array per-output
            values (it is read as one output: which value is meant?).
        """
        n_act = detector.n_out_active
        if n_act == detector.n_out:
            return self
        width = detector.naxis1 // detector.n_out
        first = detector.x0 // width
        last = (detector.x0 + detector.nx - 1) // width
        changes = {}
        for name in _PER_OUTPUT:
            value = getattr(self, name)
            if not (isinstance(value, tuple) and len(value) == detector.n_out
                    and len(value) != n_act):
                continue
            if first != last:
                raise ParameterError(
                    f"{name!r} has {len(value)} per-output values of the full array, "
                    f"but the window (columns {detector.x0}..{detector.x0 + detector.nx - 1}"
                    f") spans its outputs {first}..{last} and is read as one: give "
                    f"{name!r} one value")
            changes[name] = (value[first],)
        return self.replace(**changes) if changes else self

    def per_output(self, name, n_out):
        """Amplitude ``name`` as an array of ``n_out`` values (e-)."""
        value = getattr(self, name)
        if isinstance(value, tuple):
            if len(value) != n_out:
                raise ParameterError(
                    f"{name!r} has {len(value)} per-output values but the readout uses "
                    f"{n_out} outputs")
            return np.asarray(value, dtype=float)
        return np.full(n_out, float(value))

    def enabled(self, name):
        """True if component ``name`` has any non-zero amplitude."""
        value = getattr(self, name)
        if isinstance(value, tuple):
            return any(v > 0 for v in value)
        return value > 0

    def is_silent(self):
        """True if no component adds anything to a frame (every amplitude is 0; RTN
        counts only with ``rtn_fraction > 0``), so a generator can be skipped."""
        for f in dataclasses.fields(self):
            if f.name in _OPTIONS or (f.name == "rtn_amp" and self.rtn_fraction == 0):
                continue
            value = getattr(self, f.name)
            if any(v != 0 for v in (value if isinstance(value, tuple) else (value,))):
                return False
        return True

    def replace(self, **changes):
        """Return a copy with ``changes`` applied (validated)."""
        return dataclasses.replace(self, **changes)

    def to_header_cards(self):
        """``(key, value, comment)`` FITS cards recording every parameter."""
        def val(v):
            if isinstance(v, tuple):
                return ",".join(f"{x:g}" for x in v) if not isinstance(v[0], tuple) else \
                    ";".join(f"{a:g}:{b:g}" for a, b in v)
            return v
        cards = [
            ("RDNOISE", val(self.rd_noise), "[e-] white read noise per read (not CDS)"),
            ("REFRATIO", self.ref_ratio, "reference/regular white-noise ratio"),
            ("C_PINK", self.c_pink, "[e-] correlated 1/f, sigma per frame"),
            ("U_PINK", val(self.u_pink), "[e-] uncorrelated 1/f, sigma per frame"),
            ("ACN", val(self.acn), "[e-] alternating column noise, sigma per frame"),
            ("PCA0AMP", self.pca0, "[e-] picture-frame noise, sigma per frame"),
            ("PEDESTAL", self.pedestal, "[e-] per-frame pedestal sigma"),
            ("KTCNOISE", self.ktc, "[e-] kTC reset noise per integration"),
            ("BIASOFF", self.bias_offset, "[e-] bias offset"),
            ("BIASAMP", self.bias_amp, "[e-] bias pattern amplitude"),
            ("RTNFRAC", self.rtn_fraction, "fraction of RTN pixels"),
            ("RTNAMP", self.rtn_amp, "[e-] RTN step"),
            ("RTNTLOW", self.rtn_tau_low, "[s] RTN mean dwell, low state"),
            ("RTNTHIGH", self.rtn_tau_high, "[s] RTN mean dwell, high state"),
            ("FMIN", self.f_min, "[Hz] 1/f PSD flat below this"),
            ("PINKSPEC", val(self.pink_spectrum) if self.pink_spectrum else "1/f",
             "pink PSD shape: 1/f or f_Hz:psd pairs"),
            ("PCA0FILE", self.pca0_file or "synthetic", "picture-frame template"),
        ]
        return cards


#: The paper's defaults (Rauscher 2015, Table 1): a NIRSpec-like H2RG + SIDECAR.
NIRSPEC_DEFAULTS = NoiseParams()

#: Every component off: an empty, noise-free ramp.
ZERO_NOISE = NoiseParams(rd_noise=0.0, ref_ratio=0.8, c_pink=0.0, u_pink=0.0, acn=0.0,
                         pca0=0.0, pedestal=0.0, ktc=0.0, bias_offset=0.0, bias_amp=0.0)
