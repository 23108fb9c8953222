"""Noise parameters estimated from dark ramps: the inverse of :mod:`noise.generator`.

What is fitted, and from which statistic
----------------------------------------
The data are dark ramps in electrons (DN times the gain).  Everything that does not
change between the reads of an integration (the kTC + bias reset level) cancels in a
**CDS difference** ``y = read(2m+1) - read(2m)``; the pairs do not overlap, so their
white noise is independent.  Dark current does not cancel: it leaves ``i_dark T`` in
every difference (uniform, it reads as pedestal; hot pixels read as white noise), so
it must be negligible or subtracted first.  On each output's time line
(the clock of :mod:`noise.clock`: ``t = y * (ncols_out + nroh) + x_fast`` samples, the
overhead samples being gaps), a difference is a stationary Gaussian series whose
lag covariance is known in closed form for every component of :mod:`noise.params`:

* white read noise, per read ``rd`` (regular pixels) and ``rd * ref_ratio``
  (reference pixels): ``2 sigma^2`` at lag 0;
* correlated (``c_pink``) and uncorrelated (``u_pink``) 1/f noise of the amplitude
  definition of :mod:`noise.params` (PSD ``S = amp^2 S_1``, ``S_1`` the realised PSD of
  :func:`noise.pink.realised_psd` divided by its variance over one frame with the frame
  mean removed): ``C_y(tau) = int S(f) 4 sin^2(pi f T) cos(2 pi f tau dt) df``, ``T``
  the frame time;
* ACN: independent half-rate 1/f series on the even and odd samples of the time line:
  ``C_y`` of the half-rate series at lag ``tau / 2`` for even ``tau``, 0 for odd;
* pedestal: ``2 pedestal^2`` at every lag, common to all outputs;
* picture frame: the template ``P(y, x)`` times a 1/f series sampled once per row
  (row rate, shared by all outputs), so not stationary on the time line; its
  expected periodogram is a sum over row pairs, ``sum_{r, r'} C_pf(r - r')
  G_a(r, k) G_b(r', k)^*`` with ``G(r, k)`` the DFT of row ``r`` of the masked,
  time-ordered template, done as an FFT over the rows.

The statistics are periodograms ``|F_k|^2`` of each difference's masked time line
(regular pixels, and separately reference pixels), averaged over outputs, and the
**cross-periodogram** between outputs ``Re(F_o F_o'^*)``, which only the components
common to all outputs (``c_pink``, pedestal, picture frame) reach.  The time line is
cut into segments of whole rows (all rows up to 256 rows, else 128) so that every
model term costs time linear in the frame size.  For masks ``w_a``, ``w_b`` the
expected (cross-)periodogram of a stationary component is exact, gaps and leakage
included::

    E[F_a(k) F_b(k)^*] = sum_tau C(tau) R_ab(tau) exp(-2 pi i k tau / L),
    R_ab(tau) = sum_t w_a(t + tau) w_b(t),

``L`` the samples per segment.  It is linear in the variances ``theta = (rd^2,
(rd ref_ratio)^2, c_pink^2, u_pink^2, acn^2, pedestal^2, pca0^2)``, so the fit is a
weighted linear least-squares fit of the periodograms, binned in ~40 logarithmic
frequency bins (the DC bin alone), with weights from the model variance of a bin
(each ordinate an exponential: its chi^2_2 statistics; three reweighting passes).
The covariance of ``theta`` is the sandwich estimate: the fit is a linear map ``H``
of the statistics, applied to each difference on its own, and the covariance of the
mean of those ``n_diff`` estimates is their sample covariance over ``n_diff``.  It
needs no assumption about how the ordinates are correlated within a difference,
only that different differences are nearly independent (true for white noise and
pedestal; for 1/f noise their correlation is weak at the fitted frequencies, above
1 / T).  (Overlapping differences with a lag-1 Newey-West covariance were tried:
their pull widths were 1.1-1.18, too narrow errors, so they are not used.)

A variance measured from ``n_diff`` values with an uncertainty from their own
scatter has skewed pulls: the pedestal, one offset per frame, is the extreme case
(mean pull about ``-sqrt(2 / n_diff)`` in variance, -0.2 in amplitude at 32
differences; docs/NOISE_CALIBRATION.md).

The reset level is fitted from the mean of each integration's reads, ``M``:

* ``ktc``: the per-pixel variance of ``M`` over integrations (each pixel's value
  minus the mean of its row, output and column parity (ACN's two series), which removes pedestal and 1/f banding, and minus
  the row's projection on the template, which removes the picture frame's drift),
  minus the variance of the read noise in ``M``, which ``(mean of the even reads -
  mean of the odd reads) / 2`` estimates without any reset level; divided by the
  fraction ``1 - 1/m - h`` of an iid variance those projections keep (``m`` pixels
  in the row and output, ``h`` the template's leverage).  Its uncertainty is the
  scatter over pixels.
  **Not identifiable from one integration** (kTC and the fixed bias pattern are then
  one image): an upper bound is given.
* ``bias_amp``: regression of the integration-averaged ``M`` on the template of
  :func:`noise.template.template_for` (the synthetic one unless a file is given),
  both with their row-and-output means removed; ``bias_offset``: the mean of ``M`` over
  regular pixels minus ``bias_amp`` times the template's mean.  The offset is known
  only to within the slow 1/f drift of the whole exposure, which depends on
  ``f_min`` (not identifiable from a ramp): its uncertainty is that drift's variance
  under the fitted model and the ``f_min`` given (the frame mean of the common pink
  averaged over every read slot, integrations laid out on one clock), plus the
  pedestal's and kTC's share.

Not fitted (reported as such, with no value): random telegraph noise, and
``f_min`` (a ramp of frames does not reach 1e-4 Hz; the value given is used for the
model PSD).  Per-output amplitudes are fitted as one value common to all outputs.
The bias pattern's uncertainty includes the picture frame's drift averaged over the
reads (proportional to the template row by row, so indistinguishable from it).

Identifiability.  ``c_pink`` and ``u_pink`` need two or more outputs (with one, only
``hypot(c_pink, u_pink)`` is seen: it is reported as ``c_pink``); ``ref_ratio`` needs
reference pixels; ``ktc`` needs two or more integrations.  A component whose variance
is below twice its uncertainty is reported with an upper bound ``sqrt(theta + 2
sigma)`` (97.7 % one-sided) besides its value.

Data in DN are converted with the gain; the ADC's rounding adds ``gain^2 / 12`` to
the white variance per read, which is subtracted.  A file's own ``GAIN`` and detector
cards win: options that contradict them are refused, and so are darks of different
gains together.  Measured round trips are in ``docs/NOISE_CALIBRATION.md``.

Jumps.  Charge that arrives between two reads (cosmic rays; hot or lit pixels) is not
noise: a read step more than :data:`_JUMP_SIGMA` robust sigmas (of the pixels of its
kind, regular or reference, and output) above its row and output's median is a jump
(:func:`_find_jumps`).  A CDS difference with one takes
its row and output's median at that pixel (the 1/f banding stays, the pixel's own
white noise of that difference is lost: a negligible share), and a pixel with one in
any integration is left out of the reset-level fit (kTC, bias).  Smaller jumps are
not seen one by one, but a pixel that collects charge all along (hot or lit) is
found by the sum of its steps (``last - first`` read, summed over integrations, more
than :data:`_JUMP_SIGMA` robust sigmas above its row and output's median): every
difference of its takes the median.  The white-noise model keeps the share of
samples not replaced.  Notes say how many were found.
"""

import functools
import json
import math
import os
from dataclasses import dataclass, field, replace as _replace_fields

import numpy as np
import scipy.fft as sfft

from noise.clock import Detector, detector_from_header
from noise.errors import FileFormatError, ParameterError, ParameterTypeError
from noise.fitsio import open_fits
from noise.params import NoiseParams, check_pink_spectrum
from noise.pink import _realised_psd, _unit_frame_variance
from noise.template import template_for
from noise.validate import check_float, check_instance, describe

__all__ = ["Estimate", "CalibrationResult", "DarkRamps", "load_darks", "calibrate_darks",
           "dark_psd", "PSD_COMPONENTS", "MIN_DIFFERENCES", "FITTED_PARAMETERS"]

#: Components of the periodogram fit, in the order of ``theta``.
PSD_COMPONENTS = ("white", "white_ref", "c_pink", "u_pink", "acn", "pedestal", "pca0")
#: CDS differences (non-overlapping read pairs, all integrations) the fit needs: its
#: covariance is the scatter over them.
MIN_DIFFERENCES = 8
#: Parameters with a value and an uncertainty when identifiable (pull-tested, except
#: ``bias_offset``; see the module notes).
FITTED_PARAMETERS = ("rd_noise", "ref_ratio", "c_pink", "u_pink", "acn", "pedestal",
                     "pca0", "ktc", "bias_amp", "bias_offset")

_NBINS = 40          # logarithmic frequency bins (DC bin apart)
_OVERSAMPLE = 16     # frequency grid points per 1 / T for the lag covariances
_IRLS_PASSES = 3
_DETECT = 2.0        # theta below this many sigma: an upper bound is given too
#: A read step this many robust sigmas above its row and output's median is a jump
#: (:func:`_find_jumps`).
_JUMP_SIGMA = 6.0
#: The bias pattern is regressed on the template only where the template's rms
#: within rows and outputs (in its own unit, a robust sigma of 1 over the full
#: array) reaches this: below it a bias_amp of 1000 e- would vary by < 1 e- within
#: a row, and a window of a full-size array (float32 steps of ~1e-5 in a template
#: constant along rows) gave bias_amp 25331 +- 24263 for 500 (a probe).
_TEMPLATE_MIN_RMS = 1e-3


@dataclass(frozen=True)
class Estimate:
    """One fitted parameter.

    Parameters
    ----------
    name : str
        The :class:`~noise.params.NoiseParams` field.
    value : float or None
        Best estimate (e-, or a ratio for ``ref_ratio``); None when not identifiable.
    sigma : float or None
        1-sigma uncertainty of ``value``.
    upper : float or None
        Upper bound (97.7 %, one-sided): when the component is not detected (its
        variance below twice its uncertainty) or not identifiable.
    note : str
        Why a value is missing or how to read it.
    """

    name: str
    value: float | None
    sigma: float | None
    upper: float | None = None
    note: str = ""


@dataclass(frozen=True)
class DarkRamps:
    """Dark integrations in electrons, ready for :func:`calibrate_darks`.

    Parameters
    ----------
    integrations : tuple of ndarray
        One array per integration, shape (nreads, ny, nx), float32 or float64, e-.
    detector : noise.clock.Detector
        Geometry and clock of the data.
    gain : float or None
        e-/DN if the data were digitised (the ADC rounding is then removed from the
        white noise), None for electrons.
    sources : tuple of str
        File names, for the record.
    """

    integrations: tuple
    detector: Detector
    gain: float | None = None
    sources: tuple = ()


@dataclass(frozen=True)
class CalibrationResult:
    """What :func:`calibrate_darks` measured.

    Attributes
    ----------
    estimates : dict of str to Estimate
        Every parameter of :data:`FITTED_PARAMETERS` plus ``rtn_fraction`` (not
        fitted).
    params : noise.params.NoiseParams
        The fitted model: fitted values, unfitted components 0 (``f_min`` and the
        template as given).
    theta, theta_cov : ndarray
        The periodogram fit's variances (e-^2, :data:`PSD_COMPONENTS`; NaN when a
        component is not in the fit) and their covariance.
    psd : dict
        Frequencies (Hz, bin centres), the binned periodograms (mean, sigma) and the
        fitted model (total and per component), per statistic (``'auto'``, ``'cross'``,
        ``'ref'``): see :func:`dark_psd`.
    n_diff, n_int : int
        CDS differences and integrations used.
    detector : noise.clock.Detector
    notes : tuple of str
    """

    estimates: dict
    params: NoiseParams
    theta: np.ndarray
    theta_cov: np.ndarray
    psd: dict
    n_diff: int
    n_int: int
    detector: Detector
    notes: tuple = field(default=())

    def to_toml(self, *, sources=()):
        """A ``[noise]`` table for a scene file, with uncertainties as comments."""
        lines = ["# noise parameters fitted from dark ramps by scenesim (noise.calibrate)"]
        for src in sources:
            lines.append(f"# input: {src}")
        det = self.detector
        lines.append(f"# detector: {det.name} {det.ny}x{det.nx}, {det.n_out_active} "
                     f"outputs, dt = {det.dt:g} s; {self.n_int} integrations, "
                     f"{self.n_diff} CDS differences")
        lines.append("# values: e- (read noise per read, not CDS); '+-' 1 sigma; keys "
                     "left out are 0 (preset 'none')")
        for note in self.notes:
            lines.append(f"# note: {note}")
        lines += ["", "[noise]", 'preset = "none"']
        for name in FITTED_PARAMETERS + ("rtn_fraction",):
            est = self.estimates[name]
            comment = []
            if est.sigma is not None:
                comment.append(f"+- {est.sigma:.4g}")
            if est.upper is not None:
                comment.append(f"upper bound {est.upper:.4g}")
            if est.note:
                comment.append(est.note)
            text = "; ".join(comment)
            if est.value is None:
                lines.append(f"# {name}: not fitted" + (f" ({text})" if text else ""))
            else:
                # the model's value: an amplitude below 0 (a bias pattern
                # anti-correlated with the template) is written as 0
                value = getattr(self.params, name)
                lines.append(f"{name} = {value:.6g}" + (f"    # {text}" if text else ""))
        lines.append(f"f_min = {self.params.f_min:g}    # Hz, assumed (not identifiable "
                     f"from a ramp)")
        if self.params.pink_spectrum is not None:
            pairs = ", ".join(f"[{f:g}, {p:g}]" for f, p in self.params.pink_spectrum)
            lines.append(f"pink_spectrum = [{pairs}]")
        if self.params.pca0_file is not None:
            lines.append(f"pca0_file = {json.dumps(self.params.pca0_file)}")
        return "\n".join(lines) + "\n"


# --------------------------------------------------------------------- input files
def _as_detector(detector):
    if detector is None:
        return None
    return check_instance("detector", detector, Detector, "a noise.Detector")


def load_darks(paths, *, detector=None, gain=None):
    """Read dark ramps from FITS files into :class:`DarkRamps`.

    Accepted: scenesim noise files (``scenesim noise``: float32 e- or uint16 DN,
    detector cards in the header) and files whose data are in a ``SCI`` extension
    (e.g. JWST uncal), shape (nreads, ny, nx) or (nints, nreads, ny, nx), one frame
    per group (``NFRAMES = 1``, ``GROUPGAP = 0``).

    Parameters
    ----------
    paths : sequence of str
        One or more files of the same detector and image size.
    detector : noise.Detector, optional
        Geometry and clock of files without scenesim detector cards (required for
        them); a file whose cards give another detector is refused.
    gain : float, optional
        e-/DN for data in DN without a ``GAIN`` card; a file that records another
        gain is refused (files of different gains are refused too: the ADC's
        rounding is taken out for one gain).

    Raises
    ------
    noise.errors.FileFormatError
        A file is unreadable, has no 3-D or 4-D data, or averages frames per group.
    noise.errors.ParameterError
        Files of different geometry, no gain for DN data, no detector for a file
        without the scenesim cards, one file named twice (under any spelling).

    Notes
    -----
    The ramps must be darks: charge collected at ``lam`` e- per frame adds ``lam / 2``
    to the white variance per read that :func:`calibrate_darks` reports (a dark
    current of 0.01 e-/s adds 0.05 e-^2 at NIRSpec's 10.7 s frames).  Nothing here
    tells a dark from a lit exposure.
    """
    if isinstance(paths, (str, bytes)) or not hasattr(paths, "__iter__"):
        paths = [paths]
    paths = list(paths)
    if not paths:
        raise ParameterError("'paths' must name at least one dark file, got none")
    for j, path in enumerate(paths):       # one file twice would count as two darks
        for first in paths[:j]:
            try:
                same = os.path.samefile(first, path)
            except (OSError, TypeError, ValueError):  # missing: named by open_fits below
                same = False
            if same:
                raise ParameterError(
                    f"dark ramps {first!r} and {path!r} are the same file: each dark is "
                    f"counted once (twice would shrink the uncertainties by sqrt(2))")
    detector = _as_detector(detector)
    if gain is not None:
        gain = check_float("gain", gain, minimum=0.0, strict_min=True)
    ints, det_all, gain_all, dn_any = [], None, None, False
    for path in paths:
        with open_fits(path, "dark ramp", memmap=False) as hdul:
            hdr0 = hdul[0].header
            hdu = hdul[0] if hdul[0].data is not None else (
                hdul["SCI"] if "SCI" in hdul else None)
            if hdu is None:
                raise FileFormatError(f"dark ramp {path!r} has no data in its primary "
                                      f"HDU and no 'SCI' extension")
            hdr = hdu.header
            data = _read_order(path, np.asarray(hdu.data), hdr, hdr0)
            scenesim_file = hdr0.get("FILETYPE") == "noise"
            if "READS" in hdul:      # a read list says more than NFRAMES/GROUPGAP
                _check_single_reads(path, hdul["READS"].data)
            if not scenesim_file:
                nfr = hdr0.get("NFRAMES", hdr.get("NFRAMES", 1))
                gap = hdr0.get("GROUPGAP", hdr.get("GROUPGAP", 0))
                if int(nfr) != 1 or int(gap) != 0:
                    raise FileFormatError(
                        f"dark ramp {path!r} has NFRAMES = {nfr} frames per group and "
                        f"GROUPGAP = {gap}: calibration needs one frame per group and no "
                        f"gap (a RAPID-like readout)")
            try:
                own = detector_from_header(hdr0)
            except FileFormatError as exc:
                if detector is None:
                    raise ParameterError(
                        f"dark ramp {path!r} has no scenesim detector cards ({exc}); "
                        f"pass the detector (--preset and its options)") from exc
                own = None
            if own is not None and detector is not None and not _same_clock(own,
                                                                             detector):
                # the file's own clock wins: a contradicting one fitted 8 outputs to a
                # 4-output dark (c_pink -5 sigma, u_pink +4 sigma, no word)
                raise ParameterError(
                    f"dark ramp {path!r} records its detector in its header "
                    f"({_clock_text(own)}); the detector given "
                    f"({_clock_text(detector)}) "
                    f"differs: leave the detector options (--preset, --naxis, --n-out) "
                    f"out for files with scenesim detector cards")
            det = own if own is not None else detector
            unit = str(hdr.get("BUNIT", hdr0.get("BUNIT", "DN"))).strip().lower()
            is_dn = unit not in ("electron", "electrons", "e", "e-")
            g = None
            if is_dn:
                recorded = hdr0.get("GAIN", hdr.get("GAIN"))
                if gain is not None and recorded is not None and not _same_gain(
                        recorded, gain):
                    # a file's own gain wins: a contradicting one halved rd_noise
                    raise ParameterError(
                        f"dark ramp {path!r} records GAIN = {recorded!r} e-/DN; 'gain' "
                        f"{gain!r} contradicts it: leave the gain out for files that "
                        f"record theirs")
                g = gain if gain is not None else recorded
                if g is None:
                    raise ParameterError(
                        f"dark ramp {path!r} is in {unit!r}: pass the gain (e-/DN) "
                        f"with --gain")
                src = "--gain" if gain is not None else f"dark ramp {path!r} header GAIN"
                try:
                    g = check_float("gain", g if isinstance(g, (int, float)) else
                                    float(g), minimum=0.0, strict_min=True)
                except (ParameterError, TypeError, ValueError) as exc:
                    raise ParameterError(f"{src}: {exc}") from exc
            if data.ndim == 3:
                data = data[None]
            if data.ndim != 4:
                raise FileFormatError(
                    f"dark ramp {path!r} has data of shape {data.shape}: expected "
                    f"(nreads, ny, nx) or (nints, nreads, ny, nx)")
            if data.shape[-2:] != det.shape:
                raise ParameterError(
                    f"dark ramp {path!r} has images of {data.shape[-2]}x"
                    f"{data.shape[-1]} but the detector reads {det.ny}x{det.nx}")
            if det_all is not None and det != det_all:
                raise ParameterError(
                    f"dark ramp {path!r} has another detector or clock than "
                    f"{paths[0]!r}; calibrate files of one detector and readout together")
            if det_all is not None and is_dn != dn_any:
                raise ParameterError(
                    f"dark ramp {path!r} is in {'DN' if is_dn else 'electrons'} and "
                    f"{paths[0]!r} in {'electrons' if is_dn else 'DN'}: calibrate darks "
                    f"of one unit together (the ADC's rounding, gain^2 / 12 per read, "
                    f"is taken out of DN data only)")
            if gain_all is not None and g is not None and g != gain_all:
                raise ParameterError(
                    f"dark ramp {path!r} has gain {g!r} e-/DN, {paths[0]!r} "
                    f"{gain_all!r}: calibrate darks of one gain together (the ADC's "
                    f"rounding, gain^2 / 12 per read, is taken out for one gain)")
            det_all = det
            gain_all = g if g is not None else gain_all
            dn_any = dn_any or is_dn
            scale = np.float32(g) if is_dn else np.float32(1.0)
            for k, cube in enumerate(data):
                try:
                    _check_samples(cube, "its data" if len(data) == 1 else
                                   f"its integration {k}")
                except ParameterError as exc:
                    raise FileFormatError(f"dark ramp {path!r}: {exc}") from exc
                ints.append(cube.astype(np.float32) * scale)
    if gain is not None and not dn_any:      # it would change nothing: say so
        raise ParameterError(
            f"'gain' {gain!r} e-/DN applies to dark ramps in DN, but "
            f"{', '.join(map(repr, paths))} {'is' if len(paths) == 1 else 'are'} in "
            f"electrons (BUNIT); leave the gain out")
    return DarkRamps(tuple(ints), det_all, gain_all if dn_any else None,
                     tuple(str(p) for p in paths))


def _check_single_reads(path, reads):
    """Refuse a file whose read table (``READS``) has a resultant of more than one
    read or a gap between reads: the CDS statistics assume single, consecutive reads
    (a read list's ``NFRAMES``/``GROUPGAP`` cards describe its first resultant only:
    a probe's 4-read averages after two single reads were fitted as single reads)."""
    names = [n.upper() for n in reads.dtype.names or ()]
    if "READS" not in names:
        return
    rows = [[int(k) for k in np.atleast_1d(r) if k >= 0]
            for r in reads[reads.dtype.names[names.index("READS")]]]
    flat = [k for r in rows for k in r]
    if any(len(r) != 1 for r in rows) or any(b - a != 1 for a, b in zip(flat, flat[1:])):
        bad = next((i for i, r in enumerate(rows) if len(r) != 1), None)
        what = (f"resultant {bad} averages {len(rows[bad])} reads" if bad is not None
                else "its reads skip frames")
        raise FileFormatError(
            f"dark ramp {path!r}: {what} (READS table); calibration needs one read per "
            f"resultant and no gap (a RAPID-like readout)")


def _read_order(path, data, hdr, hdr0):
    """``data`` (..., ny, nx) in the detector's read orientation, from the file's
    ``FASTAXIS``/``SLOWAXIS`` (a JWST file in the DMS frame): ``(1, 2)`` or none as
    it is, ``-1``/``-2`` reversed along that axis, ``(2, 1)`` transposed, ``(-2,
    -1)`` reversed on both axes and transposed; others refused.  (A probe: a
    transposed NRS1 uncal was fitted along the wrong axis, c_pink and acn read 0.)"""
    fa = hdr.get("FASTAXIS", hdr0.get("FASTAXIS"))
    sa = hdr.get("SLOWAXIS", hdr0.get("SLOWAXIS"))
    if fa is None and sa is None:
        return data
    try:
        fa, sa = int(fa), int(sa)
    except (TypeError, ValueError) as exc:
        raise FileFormatError(f"dark ramp {path!r} has FASTAXIS = {fa!r}, SLOWAXIS = "
                              f"{sa!r}: expected integers") from exc
    if (abs(fa), abs(sa)) == (1, 2):
        if fa < 0:
            data = data[..., ::-1]
        if sa < 0:
            data = data[..., ::-1, :]
        return data
    if (fa, sa) == (2, 1):
        return np.swapaxes(data, -1, -2)
    if (fa, sa) == (-2, -1):
        return np.swapaxes(data[..., ::-1, ::-1], -1, -2)
    raise FileFormatError(f"dark ramp {path!r} has FASTAXIS = {fa}, SLOWAXIS = {sa}: "
                          f"an orientation the calibration does not undo (it takes "
                          f"(1, 2), (2, 1), their reversals by sign, and (-2, -1))")


def _clock_text(det):
    """A detector's geometry and clock in a few words (messages)."""
    extra = "".join(
        [f", window {det.subarray}" if det.subarray is not None else "",
         ", IRS2" if det.interleave is not None else "",
         ", reference output" if det.ref_output else ""])
    return (f"{det.name} {det.naxis1}x{det.naxis2}, {det.n_out} outputs, "
            f"dt {det.dt:g} s, nroh {det.nroh}, nfoh {det.nfoh}{extra}")


def _same_clock(a, b):
    """True when two detectors read their pixels alike (geometry, outputs, clock,
    window, interleave), whatever their names (an uncal's DETECTOR is the JWST one,
    NRCA1, where the preset says H2RG) and pixel pitch."""
    import dataclasses
    return dataclasses.replace(a, name=b.name, pixel_pitch=b.pixel_pitch) == b


def _same_gain(recorded, gain):
    """True when a header's ``GAIN`` (any type) is ``gain`` (float) to 1e-6."""
    try:
        return math.isclose(float(recorded), gain, rel_tol=1e-6)
    except (TypeError, ValueError):
        return False


# ------------------------------------------------------------- model lag covariances
@functools.lru_cache(maxsize=16)
def _cds_lag_cov(rate, frame_samples, lag_frame, f_min, spectrum):
    """Lag covariance of the CDS difference (lag ``lag_frame`` samples) of a unit
    amplitude 1/f series (amplitude over ``frame_samples`` samples, :mod:`noise.params`),
    at lags ``0 .. lag_frame - 1`` samples (float64).

    ``C_y(tau) = int_0^{rate/2} S_1(f) 4 sin^2(pi f lag / rate) cos(2 pi f tau / rate)
    df`` on a uniform grid of ``_OVERSAMPLE`` points per ``rate / lag`` (trapezoid rule
    through an inverse real FFT; the lag period, ``_OVERSAMPLE`` frames, makes the
    wrapped-around tail, ~ (1/16)^2 of the 1/f second difference, negligible).
    """
    n = sfft.next_fast_len(_OVERSAMPLE * lag_frame, real=True)
    n += n % 2
    f = np.arange(n // 2 + 1) * (rate / n)
    s = _realised_psd(f, rate, f_min, spectrum) / _unit_frame_variance(
        rate, frame_samples, f_min, spectrum)
    s *= 4.0 * np.sin(np.pi * f * lag_frame / rate) ** 2
    c = sfft.irfft(s, n=n) * (rate / 2.0)
    return c[:lag_frame].copy()


def _lag_cov(detector, f_min, spectrum):
    """``{component: C_y(tau), tau = 0 .. L - 1}`` on an output's time line (unit
    amplitudes)."""
    L = detector.frame_samples
    rate = 1.0 / detector.dt
    pink = _cds_lag_cov(rate, L, L, f_min, spectrum)
    half = _cds_lag_cov(rate / 2, L // 2, L // 2, f_min, spectrum)
    acn = np.zeros(L)
    acn[0::2] = half[:(L + 1) // 2]
    return {"pink": pink, "acn": acn}


def _expected(cov, wa, wb):
    """``E[F_a(k) F_b(k)^*]``, k = 0 .. L/2 (real part), of a stationary series of lag
    covariance ``cov`` (lags 0 .. L-1, even) seen through masks ``wa``, ``wb`` (L,)."""
    L = wa.size
    n2 = 2 * L
    r = sfft.irfft(sfft.rfft(wa, n2) * np.conj(sfft.rfft(wb, n2)), n2)  # R_ab(tau)
    g = np.empty(n2)
    g[:L] = cov * r[:L]
    g[L] = 0.0
    g[L + 1:] = cov[1:][::-1] * r[L + 1:]
    h = g[:L] + g[L:]                      # wrap the lags modulo L
    return sfft.rfft(h).real


# ------------------------------------------------------------------ the statistics
class _Layout:
    """Masks, gather indices, row segments and frequency bins of a detector's time
    lines, and the expected statistics of every component (the model).

    Each output's frame time line (overhead rows dropped) is cut into segments of
    ``seg_rows`` rows (all rows when ``ny <= 256``, else 128; rows beyond the last
    whole segment are not used), and each segment is one periodogram of
    ``seg_rows * (ncols_out + nroh)`` samples.  Segments keep every computation,
    the picture frame's included, linear in the frame size.
    """

    def __init__(self, det, template):
        self.det = det
        self.template = template
        self._basis = {}
        self.n_out = det.n_out_active
        R = self.R = det.row_samples
        ny = det.ny
        S = self.S = ny if ny <= 256 else 128
        self.nseg = ny // S
        self.Ls = S * R
        ncol = det.ncols_out
        # position of every pixel in the (n_out, ny, R) time-order array
        self.flat = ((np.arange(det.nx) // ncol)[None, :] * (ny * R)
                     + det.pixel_sample_index())
        ref = det.reference_mask()
        regular_o = self._timeorder(~ref).astype(bool)
        ref_o = self._timeorder(ref).astype(bool)
        self.tmpl = self._timeorder(template)                        # (n_out, nseg, Ls)
        self.reg = np.all(regular_o, axis=0).astype(float)            # (nseg, Ls)
        self.ref = ref_o.astype(float)                                # (n_out, nseg, Ls)
        self.ref_pairs = np.argwhere(ref_o.sum(axis=2) >= 2)          # (o, seg) rows
        self.has_ref = self.ref_pairs.shape[0] > 0
        nk = self.Ls // 2 + 1
        edges = np.unique(np.round(np.geomspace(1, nk, _NBINS + 1)).astype(int))
        self.edges = np.concatenate([[0], edges[edges < nk]])
        self.counts = np.diff(np.concatenate([self.edges, [nk]]))
        k_lo = self.edges
        k_hi = np.concatenate([self.edges[1:], [nk]]) - 1
        self.freq = np.where(k_lo == 0, 0.0, np.sqrt(np.maximum(k_lo, 1)
                                                     * np.maximum(k_hi, 1))) / (self.Ls * det.dt)
        if self.reg.sum() < 2:
            raise ParameterError(
                f"the detector's time lines have {int(self.reg.sum())} regular pixel "
                f"samples shared by all outputs; calibration needs at least 2")
        self.norm_reg = det.dt / self.reg.sum(axis=1).mean()
        self.norm_ref = det.dt / np.mean([self.ref[o, g].sum() for o, g in self.ref_pairs]) \
            if self.has_ref else 0.0

    def pixel_weights(self):
        """``(regular, reference)`` images (ny, nx): 1 where a pixel's sample enters
        the ``'auto'`` (the regular mask shared by the outputs) or the ``'ref'``
        statistic, else 0 (a segment's tail, a mask gap, a lone reference sample)."""
        det = self.det
        ref = np.zeros_like(self.ref)
        o, g = self.ref_pairs.T
        ref[o, g] = self.ref[o, g]
        out = []
        for m in (np.broadcast_to(self.reg, self.ref.shape), ref):
            full = np.zeros((self.n_out, det.ny * self.R))
            full[:, :self.nseg * self.Ls] = m.reshape(self.n_out, -1)
            out.append(full.reshape(-1)[self.flat])
        return tuple(out)

    def _timeorder(self, image):
        """``image`` (ny, nx) as (n_out, nseg, Ls) in time order (0 in the gaps)."""
        det = self.det
        out = np.zeros(self.n_out * det.ny * self.R)
        out[self.flat] = image
        return out.reshape(self.n_out, det.ny * self.R)[:, :self.nseg * self.Ls] \
            .reshape(self.n_out, self.nseg, self.Ls)

    def bin(self, p):
        return np.add.reduceat(p, self.edges, axis=-1) / self.counts

    def cached_basis(self, f_min, spectrum):
        """:meth:`basis`, computed once per ``(f_min, spectrum)``."""
        key = (f_min, spectrum)
        if key not in self._basis:
            self._basis[key] = self.basis(f_min, spectrum)
        return self._basis[key]

    def stats(self, y):
        """Binned statistics of one CDS difference ``y`` (ny, nx): a dict of
        ``'auto'``, ``'cross'`` (2+ outputs), ``'ref'`` (with reference pixels)."""
        series = self._timeorder(y)
        F = sfft.rfft(series * self.reg, axis=-1)                    # (n_out, nseg, nk)
        p2 = F.real ** 2 + F.imag ** 2
        out = {"auto": self.bin(p2.mean(axis=(0, 1))) * self.norm_reg}
        if self.n_out > 1:
            s = F.sum(axis=0)
            cross = (s.real ** 2 + s.imag ** 2 - p2.sum(axis=0)).mean(axis=0) \
                / (self.n_out * (self.n_out - 1))
            out["cross"] = self.bin(cross) * self.norm_reg
        if self.has_ref:
            o, g = self.ref_pairs.T
            G = sfft.rfft(series[o, g] * self.ref[o, g], axis=-1)
            out["ref"] = self.bin((G.real ** 2 + G.imag ** 2).mean(axis=0)) * self.norm_ref
        return out

    def _pf_spectra(self, v):
        """Row-domain transforms of the picture-frame component seen through the
        weighted template ``v`` (n, Ls) of n series of one segment: ``Ghat`` (n, 2S,
        nk), the FFT over the rows (zero-padded to 2S) of ``G(r, k)``, the DFT of row
        ``r`` at frequency ``k / Ls``.

        The row ``r`` starts at sample ``r R`` of the segment, a phase ``exp(-2 pi i
        2k r / 2S)`` (``Ls = S R``), which shifts the row transform by ``2k``:
        ``E[F_a F_b^*] = sum_q chat[(q - 2k) mod 2S] Ghat_a(q, k) Ghat_b(q, k)^* / 2S``
        with ``chat`` the FFT of the row-lag covariance of the CDS-differenced row
        series (lags wrapped modulo 2S, exact for the ``|r - r'| < S`` a segment
        holds).
        """
        S, R, Ls = self.S, self.R, self.Ls
        G = sfft.rfft(v.reshape(v.shape[0], S, R), n=Ls, axis=-1)   # (n, S, nk)
        return sfft.fft(G, n=2 * S, axis=1)

    def basis(self, f_min, spectrum):
        """``{stat: (nbins, 7) matrix}``: expected binned statistic per unit variance
        of each :data:`PSD_COMPONENTS` entry (CDS differences), averaged over the
        segments (and outputs) exactly as the data are."""
        det, S, Ls = self.det, self.S, self.Ls
        cov = _lag_cov(det, f_min, spectrum)
        cpf = _cds_lag_cov(1.0 / det.row_time, det.ny + det.nfoh, det.ny + det.nfoh,
                           f_min, spectrum)
        cext = np.zeros(2 * S)
        cext[:S] = cpf[:S]
        cext[S + 1:] = cpf[1:S][::-1]
        nk = Ls // 2 + 1
        q = np.arange(2 * S)[:, None]
        chat = sfft.fft(cext).real[(q - 2 * np.arange(nk)[None, :]) % (2 * S)]  # (2S, nk)

        def quad(g):                  # sum_q chat[(q - 2k) mod 2S] |g(q, k)|^2
            return np.einsum("qk,qk->k", chat, g.real ** 2 + g.imag ** 2)
        zero = np.zeros(nk)
        acc = {"auto": [], "cross": [], "ref": []}
        for g in range(self.nseg):
            w = self.reg[g]
            W = sfft.rfft(w)
            ped = 2.0 * (W.real ** 2 + W.imag ** 2)
            pink = _expected(cov["pink"][:Ls], w, w)
            acn = _expected(cov["acn"][:Ls], w, w)
            pf_auto = np.zeros(nk)
            us = 0.0
            for o in range(self.n_out):                   # one output at a time (memory)
                U = self._pf_spectra((self.tmpl[o, g] * w)[None])[0]
                pf_auto += quad(U)
                us = us + U
            pf_sum = pf_auto
            pf_auto = pf_auto / (2 * S * self.n_out)
            acc["auto"].append(np.stack([np.full(nk, 2.0 * w.sum()), zero, pink, pink,
                                         acn, ped, pf_auto], axis=1))
            if self.n_out > 1:
                pf_cross = (quad(us) - pf_sum) / (2 * S) / (self.n_out * (self.n_out - 1))
                acc["cross"].append(np.stack([zero, zero, pink, zero, zero, ped, pf_cross],
                                             axis=1))
        for o, g in self.ref_pairs:
            m = self.ref[o, g]
            Wm = sfft.rfft(m)
            pk = _expected(cov["pink"][:Ls], m, m)
            pf = quad(self._pf_spectra((self.tmpl[o, g] * m)[None])[0]) / (2 * S)
            acc["ref"].append(np.stack([zero, np.full(nk, 2.0 * m.sum()), pk, pk,
                                        _expected(cov["acn"][:Ls], m, m),
                                        2.0 * (Wm.real ** 2 + Wm.imag ** 2), pf], axis=1))
        norm = {"auto": self.norm_reg, "cross": self.norm_reg, "ref": self.norm_ref}
        return {k: np.add.reduceat(np.mean(v, axis=0) * norm[k], self.edges, axis=0)
                / self.counts[:, None] for k, v in acc.items() if v}


@functools.lru_cache(maxsize=2)
def _layout(det, template_file):
    """The :class:`_Layout` of ``det`` with its template (cached: round trips and
    repeated calibrations of one detector share masks and model)."""
    return _Layout(det, template_for(det, template_file))


def _check_ramps(ramps):
    if not isinstance(ramps, DarkRamps):
        raise ParameterTypeError(
            f"'ramps' must be a noise.calibrate.DarkRamps (see load_darks), got "
            f"{describe(ramps)}")
    det = ramps.detector
    n_diff, varies = 0, False
    for i, cube in enumerate(ramps.integrations):
        shape = np.shape(cube)
        if len(shape) != 3 or shape[1:] != det.shape:
            raise ParameterError(
                f"integration {i} has shape {shape}: expected (nreads, {det.ny}, "
                f"{det.nx})")
        varies = _check_samples(cube, f"integration {i}") or varies
        n_diff += shape[0] // 2
    if n_diff < MIN_DIFFERENCES:
        raise ParameterError(
            f"the darks give {n_diff} CDS differences (non-overlapping read pairs); "
            f"calibration needs at least {MIN_DIFFERENCES}: more reads or integrations")
    if not varies:
        named = f" ({', '.join(map(str, ramps.sources))})" if ramps.sources else ""
        raise ParameterError(
            f"the darks{named} have no noise: every pixel reads the same value in every "
            f"read of every integration, so there is nothing to calibrate")
    return det


def _check_samples(cube, where):
    """Refuse a cube that is not real numbers or holds NaN or inf (naming ``where``
    and the first bad sample); return whether any pixel changes from read to read."""
    cube = np.asarray(cube)
    if cube.dtype.kind not in "iuf":
        raise ParameterError(f"{where} must be real numbers (e-), got dtype {cube.dtype}")
    if cube.dtype.kind == "f":
        bad = ~np.isfinite(cube)
        if bad.any():
            r, y, x = (int(v) for v in np.argwhere(bad)[0])
            raise ParameterError(
                f"{where} has {int(bad.sum())} NaN or inf samples (the first at read "
                f"{r}, row {y}, column {x}); calibration needs finite dark ramps")
    return bool(cube.shape[0] > 1 and np.any(cube[1:] != cube[:1]))


def _differences(ramps, jumps=None):
    """Non-overlapping CDS differences ``read(2m+1) - read(2m)`` of every
    integration, one at a time; a pixel with a jump in that read step
    (``jumps[k][2m]``, :func:`_find_jumps`) takes its row and output's median."""
    for k, cube in enumerate(ramps.integrations):
        for m in range(np.shape(cube)[0] // 2):
            y = (np.asarray(cube[2 * m + 1], dtype=np.float64)
                 - np.asarray(cube[2 * m], dtype=np.float64))
            if jumps is not None and jumps[k][2 * m].size:
                hit = jumps[k][2 * m]
                y.flat[hit] = _row_output_median(y, ramps.detector).flat[hit]
            yield y


def _row_output_median(d, det):
    """Each pixel's row-and-output median of the image ``d`` (ny, nx), as an image."""
    ny, nx = d.shape
    ncol = nx // det.n_out_active
    med = np.median(d.reshape(ny, nx // ncol, ncol), axis=2)
    return np.repeat(med, ncol, axis=1)


def _find_jumps(ramps):
    """Charge that arrived at a pixel between two reads (a cosmic ray, a lit or hot
    pixel), and pixels that never change: ``(jumps, stepped, n, hot, stuck)``.
    ``jumps[k][j]`` holds the flat indices of
    the pixels of integration ``k`` whose read step ``read(j+1) - read(j)``, less
    its row and output's median (the 1/f banding), exceeds :data:`_JUMP_SIGMA`
    robust sigmas of that step over the pixels of their kind (regular or reference)
    and output (1.4826 times the median absolute deviation), and every ``hot``
    pixel; ``stepped`` (ny, nx) the pixels with such a step; ``n`` the number
    of steps flagged; ``hot`` (ny, nx) the regular pixels whose charge over all
    integrations (their read steps less their row and output's median, summed over
    every step not flagged) exceeds :data:`_JUMP_SIGMA` robust sigmas of that sum
    over their output's regular pixels; ``stuck`` (ny, nx) the pixels whose value is
    the same in every read of every integration (no read noise: stuck, or at an
    ADC limit), whose steps are all in ``jumps`` too.

    A Gaussian step passes 6 sigma with probability 1e-9: ~0.1 false flags in 1e8
    steps, which only take their median (:func:`_differences`) or leave a pixel out
    of the reset-level fit.  Left in, the steps of ~1 % of pixels hit by cosmic rays
    biased a probe's rd_noise by +5.5 sigma, ref_ratio -8, u_pink +5 and kTC +4.
    The sum finds the hot pixels whose steps are too small to pass one by one: a
    dark current ``i`` puts ``i T`` in each of ``n`` steps but ``n i T`` in their sum,
    whose noise does not grow with ``n`` (the reads in between cancel).  Left in,
    1 % of pixels at 20-900 e-/s (4-180 e- per 0.195 s frame) had biased rd_noise by
    +15 sigma and ref_ratio by -5."""
    det = ramps.detector
    # each output's regular and reference pixels against their own spreads (one
    # spread for the array flagged the steps of an output of higher read noise, and
    # reference pixels under a strong picture frame); hot pixels among the regular
    # ones only (reference pixels collect no charge)
    regular = ~det.reference_mask()
    out, n = [], 0
    total = np.zeros(det.shape)
    lo = np.full(det.shape, np.inf)
    hi = np.full(det.shape, -np.inf)
    for cube in ramps.integrations:
        steps = []
        for j in range(np.shape(cube)[0]):
            frame = np.asarray(cube[j], dtype=np.float64)
            np.minimum(lo, frame, out=lo)
            np.maximum(hi, frame, out=hi)
        for j in range(np.shape(cube)[0] - 1):
            d = (np.asarray(cube[j + 1], dtype=np.float64)
                 - np.asarray(cube[j], dtype=np.float64))
            d -= _row_output_median(d, det)
            steps.append(np.union1d(_above_per_output(d, det, regular),
                                    _above_per_output(d, det, ~regular)))
            n += steps[-1].size
            d.flat[steps[-1]] = 0.0        # a jump is not a hot pixel's charge
            total += d
        out.append(steps)
    hot = np.zeros(det.shape, bool)
    hot.flat[_above_per_output(total, det, regular)] = True
    # a pixel whose value never changes (stuck, or at the ADC's top or bottom code
    # in every read) carries no read noise: taken as it is, 2 % of such pixels at
    # the top code moved bias_offset by +2100 e- (+700 sigma) and ref_ratio by +3 %
    stuck = hi == lo
    hot &= ~stuck
    stepped = np.zeros(det.shape, bool)
    hot_idx = np.flatnonzero(hot | stuck)
    for steps in out:
        for j, hit in enumerate(steps):
            stepped.flat[hit] = True
            if hot_idx.size:
                steps[j] = np.union1d(hit, hot_idx)
    return out, stepped & ~stuck, n, hot, stuck


def _above_per_output(d, det, mask):
    """Flat indices of the pixels of ``d`` (ny, nx) selected by ``mask`` that lie
    above :data:`_JUMP_SIGMA` robust sigmas of the selected pixels of their own
    output (:func:`_above`), sorted."""
    ncol = det.nx // det.n_out_active
    idx = np.arange(d.size).reshape(d.shape)
    found = []
    for o in range(det.n_out_active):
        cols = slice(o * ncol, (o + 1) * ncol)
        sel = mask[:, cols]
        if sel.any():
            found.append(idx[:, cols][sel][_above(d[:, cols][sel])])
    return np.sort(np.concatenate(found)) if found else np.zeros(0, np.intp)


def _above(d):
    """Flat indices of ``d`` above :data:`_JUMP_SIGMA` robust sigmas (1.4826 times
    the median absolute value; none if that is 0)."""
    sigma = 1.4826 * float(np.median(np.abs(d)))
    if sigma <= 0:
        return np.zeros(0, np.intp)
    return np.flatnonzero(d > _JUMP_SIGMA * sigma)


def _collect(ramps, lay, jumps=None):
    """Binned statistics of every difference, ``{stat: (n_diff, nbins)}``, and the
    white-noise share the median replacements kept, ``{'auto': 1 - r, 'ref': 1 -
    r_ref}``: ``r`` the fraction of the statistic's masked samples, over every
    difference, that took their row's median (:func:`_differences`), which carries
    the row's 1/f level but not the pixel's own white noise (the median's own, about
    ``pi / (2 m)`` of it for ``m`` pixels in the row and output, is neglected)."""
    per = {}
    for y in _differences(ramps, jumps):
        for k, v in lay.stats(y).items():
            per.setdefault(k, []).append(v)
    n_diff = len(per["auto"])
    kept = {"auto": 1.0, "ref": 1.0}
    if jumps is not None:
        w_reg, w_ref = lay.pixel_weights()
        taken = {"auto": 0.0, "ref": 0.0}
        for k, cube in enumerate(ramps.integrations):
            for m in range(np.shape(cube)[0] // 2):
                hit = jumps[k][2 * m]
                taken["auto"] += w_reg.flat[hit].sum()
                taken["ref"] += w_ref.flat[hit].sum()
        kept["auto"] = 1.0 - taken["auto"] / (n_diff * w_reg.sum())
        if w_ref.sum() > 0:
            kept["ref"] = 1.0 - taken["ref"] / (n_diff * w_ref.sum())
    return {k: np.array(v) for k, v in per.items()}, kept


def _fit(per, basis, cols, counts):
    """Weighted linear fit of the mean statistics (``counts``: ordinates per bin of
    each statistic); returns theta (len cols), its sandwich covariance (the sample
    covariance of the per-difference estimates ``H s_j`` over ``n_diff``), the mean
    statistics, the model and the statistics' order."""
    keys = [k for k in ("auto", "cross", "ref") if k in per]
    data = np.concatenate([per[k] for k in keys], axis=1)             # (J, nstat)
    A = np.concatenate([basis[k][:, cols] for k in keys], axis=0)      # (nstat, p)
    counts = np.concatenate([counts[k] for k in keys])
    kind = np.concatenate([[k] * basis[k].shape[0] for k in keys])
    mean = data.mean(axis=0)
    # model variance of a bin mean of K exponential ordinates (chi^2_2): mu^2 / K;
    # the cross-periodogram's ordinates have variance ~ auto^2 / (2 npairs)
    mu = np.where(kind == "cross", np.nan, np.abs(mean))
    auto = mean[kind == "auto"]
    if "cross" in per:
        mu[kind == "cross"] = np.abs(auto)
    var = mu ** 2 / counts
    for _ in range(_IRLS_PASSES):
        w = 1.0 / np.maximum(var, 1e-300)
        AtW = A.T * w
        H = np.linalg.solve(AtW @ A, AtW)
        theta = H @ mean
        model = A @ theta
        mu = np.abs(model)
        if "cross" in per:
            mu[kind == "cross"] = np.abs(model[kind == "auto"])
        var = mu ** 2 / counts
    per_diff = data @ H.T                                              # (J, p)
    cov = np.atleast_2d(np.cov(per_diff, rowvar=False)) / data.shape[0]
    return theta, cov, mean, model, keys


def _bin_counts(lay, keys, n_out):
    npairs = n_out * (n_out - 1) / 2
    out = {"auto": lay.counts * 1.0, "ref": lay.counts * 1.0,
           "cross": lay.counts * 2.0 * max(npairs, 1)}
    return {k: out[k] for k in keys}


# -------------------------------------------------------------------- the estimates
def _amp(name, theta, var, *, note="", offset=0.0):
    """Amplitude estimate ``sqrt(theta - offset)`` with delta-method sigma, and an
    upper bound when theta is below ``_DETECT`` sigma."""
    t = theta - offset
    s = math.sqrt(var) if var > 0 else float("nan")
    value = math.sqrt(max(t, 0.0))
    upper = None
    if not t > _DETECT * s:
        upper = math.sqrt(max(t + _DETECT * s, 0.0))
        sigma = None if value == 0 else s / (2 * value)
        return Estimate(name, value, sigma, upper,
                        (note + "; " if note else "") + "not detected: its variance is "
                        f"below {_DETECT:g} sigma")
    return Estimate(name, value, s / (2 * value), upper, note)


def _reset_level(ramps, lay, template, jumped=None):
    """kTC and bias estimates from the per-integration read means (module notes),
    over the regular pixels without a jump in any integration (``jumped``)."""
    det = lay.det
    ref = det.reference_mask()
    ncol = det.ncols_out
    # row x output x column-parity labels: ACN's even and odd samples have their own
    # slow offsets, which a row's mean alone left in M (a probe: kTC pulls +0.8 at
    # acn 2 e-, +6.7 at 6 e-)
    groups = ((np.arange(det.ny)[:, None] * det.n_out_active
               + (np.arange(det.nx) // ncol)[None, :]) * 2
              + (np.arange(det.nx) % 2)[None, :])
    regular = ~ref if jumped is None else ~ref & ~jumped
    lab = groups[regular]
    nlab = det.ny * det.n_out_active * 2
    m_count = np.bincount(lab, minlength=nlab).astype(float)

    def demean(v):
        s = np.bincount(lab, weights=v, minlength=nlab)
        return v - (s / np.maximum(m_count, 1))[lab]

    means, noises, offsets = [], [], []
    for cube in ramps.integrations:
        n2 = (np.shape(cube)[0] // 2) * 2
        if n2 < 2:
            continue
        c = np.asarray(cube[:n2], dtype=np.float64)
        M = c.mean(axis=0)[regular]
        N = 0.5 * (c[0::2].mean(axis=0) - c[1::2].mean(axis=0))[regular]
        means.append(M)
        noises.append(N)
        offsets.append(M.mean())
    means, noises = np.array(means), np.array(noises)
    n_int = len(means)
    # the picture frame adds pca0 * template * (its row series averaged over the
    # reads), different in every integration: within each row it is proportional
    # to the template, so it is projected out of every integration's map (with the
    # row/output means that remove pedestal and 1/f banding); for iid pixels the
    # residual keeps the fraction 1 - 1/m - h of their variance, h = T_p^2 / sum
    # over the row of T^2 (the leverage of the template column)
    T = template[regular].astype(np.float64)
    Td = demean(T)
    rows_of = np.broadcast_to(np.arange(det.ny)[:, None], det.shape)[regular]
    stt = np.bincount(rows_of, weights=Td ** 2, minlength=det.ny)
    ok = stt > 1e-12 * max(float(stt.max(initial=0.0)), 1e-300)   # rows with a pattern
    inv = np.where(ok, 1.0 / np.where(ok, stt, 1.0), 0.0)

    def clean(v):
        v = demean(v)
        coef = np.bincount(rows_of, weights=Td * v, minlength=det.ny) * inv
        return v - coef[rows_of] * Td

    factor = 1.0 - 1.0 / m_count[lab] - Td ** 2 * inv[rows_of]
    Md = np.array([clean(m) for m in means])
    Nd = np.array([clean(v) for v in noises])
    est = {}
    use = factor > 0.5            # pixels whose variance the projections mostly keep
    if n_int >= 2:
        q = (Md.var(axis=0, ddof=1) - (Nd ** 2).mean(axis=0))[use] / factor[use]
        k2 = q.mean()
        s2 = q.std(ddof=1) / math.sqrt(q.size)
        est["ktc"] = _amp("ktc", k2, s2 ** 2)
    else:
        q = (Md[0] ** 2 - Nd[0] ** 2)[use] / factor[use]
        bound = math.sqrt(max(q.mean() + _DETECT * q.std(ddof=1) / math.sqrt(q.size), 0.0))
        est["ktc"] = Estimate("ktc", None, None, bound,
                              "not identifiable from one integration: kTC and the fixed "
                              "bias pattern are one image; bound = their total rms")
    # bias pattern: regression on the template within row/output groups
    Mbar = means.mean(axis=0)
    Mbd = demean(Mbar)
    sxx = float(Td @ Td)
    if sxx > 0 and math.sqrt(sxx / Td.size) >= _TEMPLATE_MIN_RMS:
        b = float(Td @ Mbd) / sxx
        resid = Mbd - b * Td
        s_b = math.sqrt(float(resid @ resid) / (resid.size - nlab - 1) / sxx)
        row_weights = np.bincount(rows_of, weights=Td ** 2, minlength=det.ny) / sxx
        est["bias_amp"] = Estimate("bias_amp", b, s_b, None,
                                   "regression on the template" if b > 0 else
                                   "regression on the template (negative: the pattern "
                                   "is anti-correlated with it)")
    else:
        b, s_b, row_weights = 0.0, None, None
        est["bias_amp"] = Estimate("bias_amp", None, None, None,
                                   "the template has no structure within rows here")
    level, tbar = float(np.mean(offsets)), float(T.mean())
    return est, n_int, (level, tbar, int(T.size)), \
        [2 * (np.shape(c)[0] // 2) for c in ramps.integrations], (s_b, row_weights)


def _slot_comb(det, nreads, f_min):
    """Frequency grid (Hz) and ``|sum_s exp(2 pi i f s T)|^2 / N^2`` over the ``N`` read
    slots of the integrations (``nreads`` reads each, laid out on one clock as
    :mod:`noise.clock` does: a reset slot, then the reads).

    A logarithmic grid (1000 points) from ``f_min / 1000`` where the comb is ~1, then a linear grid
    resolving it (8 points per ``1 / (span T)``) up to ``64 / T`` (or the row
    Nyquist frequency); beyond, the frame and row averages (Fejer kernels, ~ ``1 /
    (pi f T)^2``) leave < 1e-4 of the totals below.
    """
    T = det.frame_time
    span = sum(1 + n for n in nreads)
    f_top = min(64.0 / T, 0.5 / det.row_time)
    f_lo = min(0.25 / (span * T), f_top / 2)
    f = np.concatenate([np.geomspace(f_min * 1e-3, f_lo, 1000, endpoint=False),
                        np.arange(f_lo, f_top, 0.125 / (span * T))])
    z = np.exp(2j * np.pi * f * T)
    small = np.abs(1 - z) < 1e-9
    acc = np.zeros(f.size, complex)
    s0 = 0
    for n in nreads:                       # one geometric series per integration
        with np.errstate(invalid="ignore", divide="ignore"):
            geo = np.where(small, n, (1 - z ** n) / np.where(small, 1, 1 - z))
        acc += z ** (s0 + 1) * geo
        s0 += 1 + n
    return f, (acc.real ** 2 + acc.imag ** 2) / sum(nreads) ** 2


def _offset_variance(det, nreads, theta, ktc2, npix, f_min, spectrum):
    """Variance (e-^2) of the mean level over every read, regular pixel and
    integration, from the fitted model: the pink common to the outputs (``c_pink^2 +
    u_pink^2 / n_out``) averaged over the frames used, the pedestal, kTC.

    The frame mean of a 1/f series is the series seen through the Fejer kernel of the
    frame's samples, the mean over frames through the slot comb (:func:`_slot_comb`;
    the integrations are taken to follow each other on one clock); this part depends
    on ``f_min``.
    """
    rate, L = 1.0 / det.dt, det.frame_samples
    f, comb = _slot_comb(det, nreads, f_min)
    s1 = _realised_psd(f, rate, f_min, spectrum) / _unit_frame_variance(
        rate, L, f_min, spectrum)
    x = np.pi * f / rate
    with np.errstate(invalid="ignore", divide="ignore"):
        fej = np.where(x == 0, 1.0, (np.sin(L * x) / (L * np.sin(x))) ** 2)
    v1 = float(np.trapezoid(s1 * fej * comb, f))
    n_out = det.n_out_active
    pink = np.nan_to_num(theta[2]) + np.nan_to_num(theta[3]) / n_out
    return (max(pink, 0.0) * v1 + max(np.nan_to_num(theta[5]), 0.0) / sum(nreads)
            + max(ktc2, 0.0) / (npix * len(nreads)))


def _pattern_variance(det, nreads, row_weights, f_min, spectrum):
    """Variance of ``sum_r w_r pfbar_r`` for a unit picture-frame amplitude, ``pfbar_r``
    the row series at row ``r`` averaged over every read: what the picture frame adds
    to the bias-pattern regression (its slow drift looks like the fixed pattern)."""
    rate, n = 1.0 / det.row_time, det.ny + det.nfoh
    f, comb = _slot_comb(det, nreads, f_min)
    s1 = _realised_psd(f, rate, f_min, spectrum) / _unit_frame_variance(
        rate, n, f_min, spectrum)
    rows = np.flatnonzero(row_weights)
    omega = np.zeros(f.size)
    for chunk in np.array_split(np.arange(f.size), max(1, f.size * rows.size // 4000000)):
        ph = 2 * np.pi * np.outer(f[chunk] * det.row_time, rows)
        w = row_weights[rows]
        omega[chunk] = (np.cos(ph) @ w) ** 2 + (np.sin(ph) @ w) ** 2
    return float(np.trapezoid(s1 * omega * comb, f))


def calibrate_darks(ramps, *, f_min=1e-4, pink_spectrum=None, template_file=None):
    """Estimate :class:`~noise.params.NoiseParams` from dark ramps.

    Parameters
    ----------
    ramps : DarkRamps
        From :func:`load_darks`, or built from arrays (e-).
    f_min : float
        Frequency (Hz) below which the model 1/f PSD is flat; not identifiable from a
        ramp (module notes), used for the model PSD and written to the result.
    pink_spectrum : sequence of (f_Hz, psd) pairs, optional
        PSD shape of the pink components instead of 1/f.
    template_file : str, optional
        Bias / picture-frame template (FITS) to regress the bias pattern on; default
        the synthetic template.

    Returns
    -------
    CalibrationResult

    Raises
    ------
    noise.errors.ParameterError
        Bad arguments, or too few CDS differences (:data:`MIN_DIFFERENCES`), before
        any work.
    """
    det = _check_ramps(ramps)
    f_min = check_float("f_min", f_min, minimum=0.0, strict_min=True)
    if pink_spectrum is not None:
        pink_spectrum = check_pink_spectrum("pink_spectrum", pink_spectrum)
    NoiseParams(f_min=f_min).check_detector(det)
    lay = _layout(det, template_file)
    template = lay.template
    jumps, stepped, n_jumps, hot, stuck = _find_jumps(ramps)
    jumped = stepped | hot | stuck
    per, kept = _collect(ramps, lay, jumps)
    basis = dict(lay.cached_basis(f_min, pink_spectrum))
    for key, col in (("auto", 0), ("ref", 1)):        # the white noise the medians lost
        if key in basis and kept[key] != 1.0:
            basis[key] = basis[key].copy()
            basis[key][:, col] *= kept[key]
    n_out = det.n_out_active
    cols = [0, 2, 4, 5, 6]          # white, c_pink (= all pink), acn, pedestal, pca0
    if n_out > 1:
        cols.insert(2, 3)
    if lay.has_ref:
        cols.insert(1, 1)
    else:
        per.pop("ref", None)
    basis = {k: basis[k] for k in per}
    th, cv, mean, model, keys = _fit(per, basis, cols, _bin_counts(lay, list(per), n_out))
    theta = np.full(len(PSD_COMPONENTS), np.nan)
    theta_cov = np.full((len(PSD_COMPONENTS),) * 2, np.nan)
    theta[cols] = th
    theta_cov[np.ix_(cols, cols)] = cv
    q = 0.0 if ramps.gain is None else ramps.gain ** 2 / 12.0   # ADC rounding, e-^2
    notes = []
    est = {}
    est["rd_noise"] = _amp("rd_noise", theta[0], theta_cov[0, 0], offset=q,
                           note="per read, not CDS")
    if lay.has_ref:
        a, b = theta[1] - q, theta[0] - q
        if a > 0 and b > 0:
            r = math.sqrt(a / b)
            # delta method: d r / d a = r / (2a), d r / d b = -r / (2b)
            g = np.array([-r / (2 * b), r / (2 * a)])
            c2 = theta_cov[np.ix_([0, 1], [0, 1])]
            est["ref_ratio"] = Estimate("ref_ratio", r, float(math.sqrt(g @ c2 @ g)))
        else:
            est["ref_ratio"] = Estimate("ref_ratio", None, None, None,
                                        "white variance of a pixel class not positive")
    else:
        est["ref_ratio"] = Estimate("ref_ratio", None, None, None,
                                    "not identifiable: no reference pixels in the data")
    if n_out > 1:
        est["c_pink"] = _amp("c_pink", theta[2], theta_cov[2, 2])
        est["u_pink"] = _amp("u_pink", theta[3], theta_cov[3, 3],
                             note="one value for every output")
    else:
        est["c_pink"] = _amp("c_pink", theta[2], theta_cov[2, 2],
                             note="one output: this is hypot(c_pink, u_pink)")
        est["u_pink"] = Estimate("u_pink", None, None, None,
                                 "not identifiable with one output (c_pink holds the "
                                 "total)")
    est["acn"] = _amp("acn", theta[4], theta_cov[4, 4], note="one value for every output")
    est["pedestal"] = _amp("pedestal", theta[5], theta_cov[5, 5])
    reset, n_int, (level, tbar, npix_used), nreads, (s_b, row_weights) = _reset_level(
        ramps, lay, template, jumped)
    est.update(reset)
    if s_b is not None and np.isfinite(theta[6]) and theta[6] > 0:
        # the picture frame's drift averaged over the reads is proportional to the
        # template row by row: add its variance to the bias pattern's
        extra = theta[6] * _pattern_variance(det, nreads, row_weights, f_min, pink_spectrum)
        e = est["bias_amp"]
        est["bias_amp"] = Estimate("bias_amp", e.value, math.sqrt(s_b ** 2 + extra), None,
                                   e.note + "; sigma includes the picture frame's drift")
    ktc2 = est["ktc"].value ** 2 if est["ktc"].value is not None else est["ktc"].upper ** 2
    var_off = _offset_variance(det, nreads, theta, ktc2, int((~det.reference_mask()).sum()),
                               f_min, pink_spectrum)
    # the white read noise of the pixels and reads averaged (left out, the sigma of
    # a white-noise dark was 0 to 3x too small: a probe) ...
    rd = est["rd_noise"].value
    if rd is not None:
        var_off += float(np.mean(np.square(rd))) / (npix_used * sum(nreads))
    # ... and the bias pattern's share: bias_offset = level - bias_amp x mean(T),
    # with bias_amp taken as 0 where it came out negative (it is written as 0)
    b = est["bias_amp"].value
    if b is not None and b < 0:
        b = 0.0
        est["bias_amp"] = _replace_fields(
            est["bias_amp"], note=est["bias_amp"].note + "; written as 0, and "
            "bias_offset is the mean reset level")
    elif b is not None and s_b is not None:
        # the regression's own error only: the picture frame's drift, which
        # bias_amp's sigma adds, is proportional to the template and moves the
        # level with b x mean(template), so it cancels here (a regression probe:
        # counted, windows' pulls had widths 0.28-0.67)
        var_off += (tbar * s_b) ** 2
    off = level - (b or 0.0) * tbar
    note = (f"sigma from the fitted 1/f drift, pedestal, kTC, white noise and the bias "
            f"pattern with f_min = {f_min:g} Hz")
    if est["bias_amp"].value is None:
        tmean = float(template[~det.reference_mask()].mean())
        note = (f"the mean reset level, bias_offset + bias_amp x {tmean:.4g} (the "
                f"template's mean here): bias_amp is not identifiable in this window, "
                f"so neither is bias_offset alone; " + note)
    est["bias_offset"] = Estimate("bias_offset", off, math.sqrt(var_off), None, note)
    est["pca0"] = _amp("pca0", theta[6], theta_cov[6, 6],
                       note="picture-frame noise, with the template used")
    est["rtn_fraction"] = Estimate("rtn_fraction", None, None, None,
                                   "random telegraph noise is not fitted")
    if ramps.gain is not None:
        notes.append(f"DN converted with gain {ramps.gain:g} e-/DN; ADC rounding "
                     f"variance {q:.4g} e-^2 removed from the white noise")
    if n_jumps:
        notes.append(
            f"{n_jumps} read steps of {int(stepped.sum())} pixels jumped by more than "
            f"{_JUMP_SIGMA:g} robust sigma (cosmic rays, hot or lit pixels): those CDS "
            f"differences took their row's median, those pixels were left out of kTC "
            f"and the bias; smaller jumps are not seen and still bias the white noise "
            f"up")
    if stuck.any():
        notes.append(
            f"{int(stuck.sum())} pixels never changed value (stuck, or at the ADC's top "
            f"or bottom code in every read): every CDS difference of theirs took its "
            f"row's median, and they were left out of kTC and the bias")
    if hot.any():
        notes.append(
            f"{int(hot.sum())} pixels collected more charge over the integrations "
            f"than {_JUMP_SIGMA:g} robust sigma of the sum of their read steps (hot "
            f"or lit pixels; steps flagged as jumps left out): every CDS difference of "
            f"theirs took "
            f"its row's median, and they were left out of kTC and the bias")
    kw = {}
    for name in ("rd_noise", "ref_ratio", "c_pink", "u_pink", "acn", "pedestal", "ktc",
                 "bias_amp", "bias_offset", "pca0"):
        v = est[name].value
        if v is not None:
            kw[name] = max(v, 0.0) if name != "bias_offset" else v
    params = NoiseParams(**{**dict(rd_noise=0.0, c_pink=0.0, u_pink=0.0, acn=0.0,
                                   pca0=0.0, pedestal=0.0, ktc=0.0, bias_offset=0.0,
                                   bias_amp=0.0), **kw},
                         f_min=f_min, pink_spectrum=pink_spectrum,
                         pca0_file=template_file)
    psd = _psd_table(lay, per, basis, cols, th, mean, model, keys)
    n_diff = next(iter(per.values())).shape[0]
    return CalibrationResult(est, params, theta, theta_cov, psd, n_diff, n_int, det,
                             tuple(notes))


def _psd_table(lay, per, basis, cols, th, mean, model, keys):
    """Binned statistics and model, per statistic, for plots (PSD units: e-^2/Hz of
    a CDS difference divided by 2, i.e. a per-read white level of ``2 rd^2 dt``)."""
    out = {"freq": lay.freq, "counts": lay.counts}
    off = 0
    for k in keys:
        n = per[k].shape[1]
        J = per[k].shape[0]
        comps = {PSD_COMPONENTS[c]: basis[k][:, c] * th[i] for i, c in enumerate(cols)}
        out[k] = {"mean": mean[off:off + n],
                  "sigma": per[k].std(axis=0, ddof=1) / math.sqrt(J),
                  "model": model[off:off + n], "components": comps}
        off += n
    return out


def dark_psd(ramps, **kwargs):
    """The averaged periodograms of ``ramps`` in readout time order with the fitted
    model: ``calibrate_darks(ramps, **kwargs).psd`` (see :class:`CalibrationResult`)."""
    return calibrate_darks(ramps, **kwargs).psd
