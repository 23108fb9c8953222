"""Compare fitted slopes with the truth injected by the simulator.

The report has three parts, each in its own module:

* per true-rate bin, the slope errors against the reported and the optimal variance
  (:mod:`scenesim.validate.stats`);
* jump detection: completeness on hit pixels and false positives on clean ones
  (:mod:`scenesim.validate.jumps`);
* aperture photometry of the injected sources (:mod:`scenesim.validate.photometry`);

and optional figures (:mod:`scenesim.validate.plots`).

Fit files: the scenesim layout (:func:`scenesim.io.fitfile.read_fit`, e-/s) or a JWST rate
file (``SCI`` in DN/s, ``DQ``, ``VAR_POISSON`` and ``VAR_RNOISE`` in (DN/s)^2, or
``ERR``), converted to e- with the truth header's ``GAIN`` (e-/DN).  The layout is
detected from the extension names.

Read times: from the exposure's ``READS`` table when the exposure is given (exact for
any readout), else a MULTIACCUM rebuilt from the truth header cards ``NFRAMES``,
``NGROUPS``, ``GROUPGAP``, ``DROPFRM1``, ``TFRAME`` (exact for MULTIACCUM patterns
only; a note says so).  A global reset shifts all read times of a pixel together,
which leaves ``V_opt`` unchanged, so the rolling-reset times are used for both.

Bad files: :func:`compare_files` checks, before any work, every truth-header card the
comparison reads (:func:`check_truth_header`: ``GAIN``, ``TFRAME`` against the
detector cards' frame time, ``NINTS`` against the ``SATGROUP`` planes, the readout
cards, ``RDNOISE``, ``ADCBITS``, ``FULLWELL``), so a corrupt value is one
:class:`~noise.errors.FileFormatError` line naming the file and the card, not a
numpy error or an overflow deep inside; and every other error about a file's
content names that file.
"""

import math
import numbers
import os
from dataclasses import dataclass, field

import numpy as np

from noise.clock import detector_from_header
from noise.adc import averaging_noise
from noise.errors import FileFormatError, ParameterError, ParameterTypeError
from noise.params import MAX_AMPLITUDE
from noise.validate import (check_bool, check_float, check_instance, check_int,
                            check_path, describe, is_sequence)

from scenesim.detector.ipc import ipc_noise_gain, undo_ipc
from scenesim.detector.readout import Readout
from scenesim.io.exposure import read_exposure_header, read_truth
from scenesim.io.header import (exposure_read_noise, exposure_settings,
                                header_ipc_deconvolved, header_ipc_kernel, header_psf,
                                readout_from_header, readout_from_table)
from scenesim.detector.dq import DO_NOT_USE, REFERENCE_PIXEL
from scenesim.io.fitfile import fit_arrays, read_slopes
from scenesim.outputs import check_plot_dir
from scenesim.pipelines.products import (fit_header, header_refmask, subtract_dark,
                                        subtracted_dark_rate)
from scenesim.rampfit import check_read_times, ols_variance
from scenesim.sky.psf import AiryPSF, GaussianPSF, ImagePSF
from scenesim.validate.jumps import jump_stats, ramp_windows
from scenesim.validate.photometry import source_photometry
from scenesim.validate.plots import plot_report
from scenesim.validate.stats import DEFAULT_EDGES, bin_rows, usable_variance

__all__ = ["DEFAULT_EDGES", "Report", "compare", "compare_files", "check_truth_header",
           "check_compare_inputs", "SAME_RUN_CARDS", "SAME_SOURCE_CARDS"]


# ---------------------------------------------------------------------- report
@dataclass(frozen=True)
class Report:
    """Result of :func:`compare`.

    Attributes
    ----------
    rows : list of dict
        One dict per flux bin: ``lo``, ``hi`` (e-/s), ``n_regular`` (regular pixels),
        ``n`` (of which not ``DO_NOT_USE``), ``bias_rep``, ``chi2_rep``, ``bias_opt``,
        ``se_bias``, ``n_cl`` (its clusters), ``dof_bias``, ``p_bias``, ``std_opt``, ``std_eff``,
        ``ols_ratio``, ``chi2_fit``, ``frac_flagged`` (NaN when empty; :mod:`scenesim.validate.stats`).
    jumps : dict
        ``n_hit``, ``completeness``, ``n_clean``, ``false_positive``, ``threshold_e``.
    photometry : dict
        ``sources`` (list of dict: ``x``, ``y``, ``flux``, ``measured``, ``noise``,
        ``ratio``), ``n``, ``median_ratio``, ``median_ratio_err``, ``radius``,
        ``aperture_correction`` (encircled energy used, NaN if none).
    notes : list of str
        Skipped steps and assumptions.
    plots : list of str
        Paths of the PNG files written.
    """

    rows: list
    jumps: dict = field(default_factory=dict)
    photometry: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    plots: list = field(default_factory=list)

    def to_dict(self):
        """Plain-Python copy (lists, dicts, floats) suitable for JSON."""
        def conv(v):
            if isinstance(v, dict):
                return {k: conv(x) for k, x in v.items()}
            if isinstance(v, (list, tuple)):
                return [conv(x) for x in v]
            if isinstance(v, np.generic):
                return v.item()
            return v
        return conv({"rows": self.rows, "jumps": self.jumps,
                     "photometry": self.photometry, "notes": self.notes,
                     "plots": self.plots})

    def format(self):
        """Printable text tables (flux bins, jumps, photometry, notes)."""
        cols = [("lo", "{:>8.3g}"), ("hi", "{:>8.3g}"), ("n", "{:>8d}"),
                ("bias_rep", "{:>9.3f}"), ("chi2_rep", "{:>9.3f}"),
                ("bias_opt", "{:>9.3f}"), ("se_bias", "{:>8.3f}"), ("p_bias", "{:>8.2g}"),
                ("std_opt", "{:>8.3f}"), ("std_eff", "{:>8.3f}"),
                ("ols_ratio", "{:>9.3f}"), ("chi2_fit", "{:>9.3f}"),
                ("frac_flagged", "{:>12.4f}")]
        head = " ".join(f"{name:>{len(fmt.format(1) if 'd' in fmt else fmt.format(1.0))}}"
                        for name, fmt in cols)
        lines = ["Slopes vs truth per true-rate bin (e-/s)", head]
        for row in self.rows:
            # a statistic a bin cannot give (no pixel, or one) prints '-', not nan
            lines.append(" ".join(
                fmt.format(row[name]) if not _undefined(row[name]) else
                f"{'-':>{len(fmt.format(1.0 if 'd' not in fmt else 1))}}"
                for name, fmt in cols))
        lines += ["What each column compares (r = fit - truth):",
                  "  bias_rep, chi2_rep: mean r/sigma and r^2/sigma^2 with the errors the "
                  "fit reported (0 and 1 if right)",
                  "  bias_opt +- se_bias: mean r/sigma_opt; se_bias counts the pixels of "
                  "one output and 16 rows as one draw (correlated noise); p_bias: the "
                  "chance of so large a bias from that noise alone (Student's t over "
                  "those draws: few in a bin of few stars); an error common to a whole",
                  "    output or array (a reference correction's offsets, correlated 1/f "
                  "noise) is one draw per exposure and not in it: pool realisations "
                  "(scenesim batch) to measure a bias to that level",
                  "  std_opt: scatter against the white-read-noise optimum (> 1 with 1/f "
                  "noise even for an optimal fitter)",
                  "  std_eff: scatter against the optimum for the noise the data have "
                  "(measured read noise, ADC rounding): 1 = optimal",
                  "  ols_ratio: what equal-weight least squares reaches (sqrt(V_ols/V_opt)); "
                  "chi2_fit: the fit's own chi2",
                  "  saturated pixels are judged on their usable ramp (before SATGROUP)"]
        j = self.jumps
        if j and not j["n_hit"]:
            lines += ["", f"Jumps: no pixel was hit above the threshold "
                      f"({j['threshold_e']:.3g} e- at rate 0): completeness not measured; "
                      f"false-positive rate {j['false_positive']:.3g} of {j['n_clean']} "
                      f"clean pixels"]
        elif j:
            rule = j.get("threshold_rule", "read noise")
            lines += ["", f"Jumps (hit: CR charge > 10 sigma of a two-read difference "
                      f"({rule}; {j['threshold_e']:.3g} e- at rate 0) inside a ramp): "
                      f"completeness {j['completeness']:.4f} of {j['n_hit']} hit pixels; "
                      f"false-positive rate {j['false_positive']:.3g} of {j['n_clean']} "
                      f"clean pixels"]
        p = self.photometry
        if p and p.get("n", 0):
            spread = (f"+- {p['median_ratio_err']:.4f} over {p['n']} sources"
                      if p["n"] > 1 else "from 1 source (no scatter to give its error)")
            lines += ["", f"Aperture photometry (r = {p['radius']:g} px, aperture "
                      f"correction {p['aperture_correction']:.4f}): median measured/"
                      f"injected = {p['median_ratio']:.4f} {spread}",
                      f"{'x':>9} {'y':>9} {'flux':>11} {'measured':>11} {'ratio':>8}"]
            for s in p["sources"]:
                lines.append(f"{s['x']:>9.2f} {s['y']:>9.2f} {s['flux']:>11.4g} "
                             f"{s['measured']:>11.4g} {s['ratio']:>8.4f}")
        if self.plots:
            lines += ["", "Plots: " + ", ".join(self.plots)]
        if self.notes:
            lines += ["", "Notes:"] + [f"- {n}" for n in self.notes]
        return "\n".join(lines)


def compare(fit, truth, *, read_times=None, nints=None, read_noise=None, psf=None,
            radius=4.0, edges=DEFAULT_EDGES, cr_sigma=10.0, plots=None, notes=(),
            readout=None, ipc_deconvolved=False, reference_corrected=False):
    """Compare fitted slopes with the truth.

    Parameters
    ----------
    fit : FitResult or dict
        A :class:`scenesim.io.fitfile.FitResult`, or a dict with ``slope`` (e-/s), ``var``
        ((e-/s)^2, reported), ``dq`` (uint32) of shape (ny, nx), optionally ``chi2`` and
        ``read_noise`` (e- per read).
    truth : dict
        As returned by :func:`scenesim.io.exposure.read_truth`: ``RATE_IPC`` (or ``RATE``)
        (ny, nx) e-/s, ``header``, optionally ``CRS`` and ``SOURCES`` tables.
    read_times : sequence of 1-D arrays, seconds from reset, keyword-only
        Read times of each resultant; default rebuilt from the truth header
        (:func:`readout_from_header`).
    nints : int, keyword-only
        Integrations combined in the fit; default the header's ``NINTS`` (or 1).
    read_noise : float, keyword-only
        e- per read (not CDS); default truth header ``RDNOISE``, else the fit's.
    psf : GaussianPSF, AiryPSF or ImagePSF, keyword-only
        For the aperture correction; default the PSF recorded in the truth header
        (:func:`scenesim.io.header.header_psf`: ``PSFFWHM`` or ``PSFAIRY``).
    radius : float, keyword-only
        Aperture radius, pixels (> 0).
    edges : sequence of float, keyword-only
        Increasing flux-bin edges, e-/s.
    cr_sigma : float, keyword-only
        CR detectability threshold in units of ``sqrt(2) * read_noise``.
    plots : str or None, keyword-only
        Existing directory for PNG plots; None for none.
    notes : sequence of str, keyword-only
        Notes to carry into the report.
    readout : scenesim.detector.readout.Readout or None, keyword-only
        The exposure's readout (read indices and frame slots); default rebuilt from
        the truth header (MULTIACCUM).  Gives ``read_times`` when those are not
        given, and the times that decide which cosmic rays fell inside a ramp.
    ipc_deconvolved : bool, keyword-only
        The fit undid the IPC: it is graded on ``RATE``, not ``RATE_IPC``.
    reference_corrected : bool, keyword-only
        The ramps were corrected with their reference pixels (a per-output, per-read
        offset common to an output's columns of one parity): a note says that the
        standard error of the bias leaves it out (:func:`_clusters`).

    Returns
    -------
    Report
    """
    f = fit_arrays(fit)
    if not isinstance(truth, dict) or "header" not in truth:
        raise ParameterError("'truth' must be a dict from scenesim.io.exposure.read_truth "
                             f"(with 'header'), got {type(truth).__name__}")
    edges = _check_compare_args(edges, radius, cr_sigma, plots, readout)
    if nints is not None:
        nints = check_int("nints", nints, minimum=1)
    if read_noise is not None:
        read_noise = check_float("read_noise", read_noise, minimum=0.0)
    if read_times is not None:
        check_read_times(read_times)
    check_instance("psf", psf, (GaussianPSF, AiryPSF, ImagePSF),
                   "a GaussianPSF, AiryPSF or ImagePSF", allow_none=True)
    check_bool("ipc_deconvolved", ipc_deconvolved)
    check_bool("reference_corrected", reference_corrected)
    if isinstance(notes, (str, bytes)) or not is_sequence(notes) or \
            not all(isinstance(n, str) for n in notes):
        raise ParameterTypeError(f"'notes' must be a sequence of strings, got "
                                 f"{describe(notes)}")
    notes = list(notes)
    hdr = truth["header"]
    rate, kernel = _true_rate(truth, ipc_deconvolved, notes)
    if rate.shape != f["slope"].shape:
        raise FileFormatError(
            f"truth rate shape {rate.shape} does not match the fit's slope shape "
            f"{f['slope'].shape}")
    read_noise = _read_noise(read_noise, hdr, f, kernel)
    if read_times is None:
        readout, read_times = _read_times(hdr, readout, notes, truth.get("READS"))
    if nints is None:
        nints = exposure_settings(hdr)["nints"]

    dq = f["dq"]
    regular = (dq & np.uint32(REFERENCE_PIXEL)) == 0
    use = regular & ((dq & np.uint32(DO_NOT_USE)) == 0)
    # the noise of a ramp is that of all the charge it collected: a pipeline's dark
    # subtraction moves the rate the fit is graded on, not the shot noise it had
    collected = rate
    if "COLLECTED" in truth:
        collected = _true_rate(truth["COLLECTED"], ipc_deconvolved, [])[0]
        notes.append("optimum and hit thresholds at the collected rate (the truth "
                     "with the dark the pipeline subtracted)")
    r0 = np.clip(collected, 0.0, None)
    satgroup = _satgroup(truth, nints, rate.shape, len(read_times), notes)
    var_opt = usable_variance(r0, read_times, read_noise, nints=nints, satgroup=satgroup)
    var_ols = usable_variance(r0, read_times, read_noise, nints=nints, satgroup=satgroup,
                              variance=ols_variance)
    rn_eff, q = _effective_noise(f, hdr, read_noise, read_times, notes)
    var_eff = usable_variance(r0, read_times, rn_eff, nints=nints, satgroup=satgroup,
                              resultant_noise=q)
    if reference_corrected:
        notes.append("se_bias and p_bias leave out the reference correction's offsets, "
                     "common to all the pixels of an output and column parity: one "
                     "draw per exposure, like the array-wide 1/f noise (in white "
                     "noise alone they moved the bias of a one-output 128^2 window by "
                     "~0.07 sigma_opt between seeds); pool realisations (scenesim "
                     "batch) to test a bias at that level")
    rows = bin_rows(f, rate, var_opt, var_eff, var_ols, edges, use, regular,
                    clusters=_clusters(hdr, rate.shape))
    jumps = _jumps(truth, dq, regular, readout, read_noise, cr_sigma, notes, collected)
    photometry = {}
    src = truth.get("SOURCES")
    if src is not None and len(src) and all(c in src.colnames for c in ("x", "y", "flux")):
        src = _light_curve_fluxes(src, truth.get("LCINTS"), notes)
        psf = header_psf(hdr) if psf is None else psf
        photometry = source_photometry(f["slope"], f["var"], ~use, src, psf,
                                       float(radius), notes)
    else:
        notes.append("photometry: no sources in the truth")
    written = plot_report(plots, f, rate, var_opt, use, rows, notes) if plots else []
    if plots is None:
        notes.append("plots: not requested")
    return Report(rows=rows, jumps=jumps, photometry=photometry, notes=notes,
                  plots=written)


def _check_compare_args(edges, radius, cr_sigma, plots, readout):
    """Validate :func:`compare`'s options; return ``edges`` as an array."""
    try:
        edges = np.asarray(edges, dtype=float)
    except (TypeError, ValueError):
        edges = np.zeros(0)
    if edges.ndim != 1 or edges.size < 2 or np.any(np.diff(edges) <= 0) \
            or np.any(np.isnan(edges)):
        raise ParameterError(
            f"'edges' must be >= 2 increasing values (e-/s), got {describe(edges)}")
    check_float("radius", radius, minimum=0.0, strict_min=True)
    check_float("cr_sigma", cr_sigma, minimum=0.0, strict_min=True)
    if plots is not None and not os.path.isdir(check_path("plots", plots)):
        raise ParameterError(f"'plots' must be an existing directory or None, got {plots!r}")
    check_instance("readout", readout, Readout, "a scenesim.detector.readout.Readout",
                   allow_none=True)
    return edges


def _true_rate(truth, ipc_deconvolved, notes):
    """The rate a fit should recover, and the IPC kernel undone on it (or None).

    ``RATE_IPC`` (after IPC), or ``RATE`` when the truth has no ``RATE_IPC``; with
    ``ipc_deconvolved`` (the fit undid IPC), ``RATE_IPC`` with the kernel undone.
    """
    if "RATE_IPC" in truth:
        rate = np.asarray(truth["RATE_IPC"], dtype=np.float64)
    elif "RATE" in truth:
        rate = np.asarray(truth["RATE"], dtype=np.float64)
        notes.append("truth has no RATE_IPC: compared with RATE (before IPC)")
    else:
        raise FileFormatError("truth has neither 'RATE_IPC' nor 'RATE'")
    kernel = None
    if ipc_deconvolved and "RATE_IPC" in truth:
        kernel = header_ipc_kernel(truth["header"])
        if kernel is not None:
            rate = undo_ipc(rate, kernel, tolerance=1e-9 * max(1.0, np.abs(rate).max()),
                            refmask=header_refmask(truth["header"], rate.shape,
                                                   "the truth's RATE_IPC"))
            notes.append("fit undid IPC (IPCDECON): compared with RATE_IPC with the "
                         "IPCKERN kernel undone")
    return rate, kernel


def _read_noise(read_noise, hdr, f, kernel):
    """Read noise per read (e-): given, else the truth header's, else the fit's;
    times the IPC deconvolution's noise gain when the fit undid IPC."""
    if read_noise is None:
        read_noise = exposure_read_noise(hdr, default=None)
        if read_noise is None:
            read_noise = f["read_noise"]
        if read_noise is None:
            raise ParameterError("'read_noise' not given and neither the truth header "
                                 "(RDNOISE) nor the fit has it")
    read_noise = float(read_noise)
    if kernel is not None:        # undoing IPC amplified the white read noise
        read_noise *= ipc_noise_gain(kernel)
    return read_noise


def _light_curve_fluxes(src, lcints, notes):
    """``src`` with each variable source's collected flux (``flux_on_array``) at its
    mean over the integrations (``LCINTS``), the rate ``RATE`` holds, which the
    exposure's slopes measure (before, its constant flux: a source in a dip read
    0.59)."""
    if lcints is None or not len(lcints) or "flux_on_array" not in src.colnames:
        return src
    src = src.copy()
    rows = np.asarray(lcints["SOURCE"], dtype=int)
    flux = np.asarray(lcints["FLUX"], dtype=float)
    for r in np.unique(rows):
        src["flux_on_array"][r] = flux[rows == r].mean()
    notes.append(f"photometry: {np.unique(rows).size} variable source(s) at their "
                 f"light curves' mean over the integrations (LCINTS)")
    return src


def _read_times(hdr, readout, notes, reads=None):
    """``(readout, read_times)`` from the readout given, else the truth's ``READS``
    table, else (a truth written before it had one) the header's MULTIACCUM cards,
    refused when they disagree with the truth's ``NREADS`` or ``EFFINTTM`` (an MA
    table or explicit resultants: their read times are the exposure's)."""
    t_frame = exposure_settings(hdr)["t_frame"]
    if t_frame is None:
        raise FileFormatError("truth header lacks 'TFRAME'; pass 'read_times' or the "
                              "exposure file")
    if readout is None and reads is not None:
        readout = readout_from_table(hdr, reads)
        notes.append("read times from the truth's READS table")
    elif readout is None:
        readout = readout_from_header(hdr)
        # before: a report from the wrong read times (std_opt 0.26-0.29 where the
        # right ones give 1.07-1.5) with only a note
        rebuilt = {"NREADS": readout.nreads,
                   "EFFINTTM": readout.effective_integration_time(t_frame)}
        for key, value in rebuilt.items():
            if key in hdr and not math.isclose(float(hdr[key]), value, rel_tol=1e-6,
                                               abs_tol=1e-9):
                raise FileFormatError(
                    f"the truth records a readout that is not MULTIACCUM (READPATT = "
                    f"{hdr.get('READPATT', '?')!r}: {key} = {hdr[key]!r}, but NGROUPS, "
                    f"NFRAMES and GROUPGAP give {value!r}) and has no READS table; its "
                    f"read times are in the exposure file: pass it (--exposure)")
        notes.append("read times rebuilt as MULTIACCUM from the truth header")
    return readout, readout.read_times(t_frame)


def _satgroup(truth, nints, shape, ngroups, notes):
    """The truth's ``SATGROUP`` as (nints, ny, nx), or None (no saturation known)."""
    sat = truth.get("SATGROUP")
    if sat is None:
        notes.append("truth has no SATGROUP: the optimum assumes every resultant usable")
        return None
    sat = np.asarray(sat)
    if sat.ndim == 2:
        sat = sat[None]
    if sat.shape != (nints,) + tuple(shape):
        notes.append(f"truth SATGROUP shape {sat.shape} does not match: ignored")
        return None
    return sat if np.any((sat >= 0) & (sat < ngroups)) else None


def _effective_noise(f, hdr, read_noise, read_times, notes):
    """Read noise per read and per-resultant rounding noise of the data (``std_eff``).

    The fit's measured read noise (it holds every white per-read term, the ADC's
    included) when it has one, else the model's with ``gain^2 / 12`` added; and the
    rounding of each on-board average of ``N > 1`` reads, ``gain^2 / 12 (1 -
    1/N^2)`` for odd ``N``, ``(1 + 2/N^2)`` for even (:func:`noise.adc.averaging_noise`;
    stats module notes).
    """
    gain = exposure_settings(hdr)["gain"] or 0.0
    if gain == 0.0:
        notes.append("std_eff: no GAIN in the truth header: ADC rounding left out")
    if f.get("read_noise") is not None:
        rn = float(f["read_noise"])
    else:
        rn = float(np.sqrt(read_noise ** 2 + gain ** 2 / 12.0))
        notes.append("std_eff: the fit file has no measured read noise: the model's "
                     "is used, with the ADC's gain^2/12")
    n = [np.size(t) if np.ndim(t) == 1 else np.shape(t)[0] for t in read_times]
    return rn, averaging_noise(gain, n)


def _clusters(hdr, shape, rows=16):
    """Labels of pixels sharing correlated noise: one output (its columns, from the
    detector cards; else blocks of 64 columns) and one band of ``rows`` rows.

    Not an error common to a whole output: a reference correction's offsets (a
    probe: white read noise only, the 'jwst' correction, a 128^2 window read through
    one output, the bias of the 10-100 e-/s bin scattered by 0.07 sigma_opt between
    seeds where se_bias said 0.010).  Clusters of whole outputs were tried
    (2026-11-28) and dropped: a window read through one output has two (its column
    parities), and a standard error of one degree of freedom; the report says so in
    a note instead (:func:`compare`)."""
    ny, nx = shape
    try:
        det = detector_from_header(hdr)
        col = det.output_of_column() if det.shape == tuple(shape) else None
    except (FileFormatError, ParameterError, KeyError, ValueError):
        col = None
    if col is None:
        col = np.arange(nx) // 64
    band = np.arange(ny) // rows
    return band[:, None] * (int(np.max(col)) + 1) + np.asarray(col)[None, :]


def _jumps(truth, dq, regular, readout, read_noise, cr_sigma, notes, rate):
    """Jump completeness and false positives (:func:`jump_stats`), or ``{}``."""
    crs = truth.get("CRS")
    if crs is None or not all(c in crs.colnames for c in ("X", "Y", "CHARGE", "SEEN")):
        notes.append("jumps: truth has no CRS table with X, Y, CHARGE, SEEN: skipped")
        return {}
    hdr = truth["header"]
    settings = exposure_settings(hdr)
    windows = None
    if readout is None and settings["t_frame"] is not None and "NGROUPS" in hdr:
        try:
            readout = readout_from_header(hdr)
        except FileFormatError:
            readout = None
    if readout is not None and settings["t_frame"] is not None:
        windows = ramp_windows(truth, readout, settings["t_frame"])
    if windows is None:
        notes.append("jumps: no detector cards or readout in the truth: every seen "
                     "deposit counts as a hit, even one before the first read")
    return jump_stats(dq, crs, dq.shape, read_noise, cr_sigma, regular,
                      windows=windows, ipc=settings["ipc"], rate=rate,
                      t_read=settings["t_frame"])


#: Cards of a truth header that :func:`compare` reads as integers, and as numbers.
_INT_CARDS = ("NINTS", "NGROUPS", "NFRAMES", "GROUPGAP", "DROPFRM1", "ADCBITS")
_FLOAT_CARDS = ("GAIN", "TFRAME", "FULLWELL")


def _check_cards(hdr):
    """Check the cards of an exposure or truth header that the comparison reads (see
    :func:`check_truth_header`); return :func:`exposure_settings` of it."""
    for key in _INT_CARDS + _FLOAT_CARDS:
        if key in hdr:
            value = hdr[key]
            kinds = numbers.Integral if key in _INT_CARDS else numbers.Real
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, kinds):
                raise FileFormatError(
                    f"{key!r} must be {'an integer' if key in _INT_CARDS else 'a number'}"
                    f", got {describe(value)}")
    settings = exposure_settings(hdr)
    if settings["gain"] is not None:
        check_float("GAIN", settings["gain"], minimum=0.0, strict_min=True,
                    maximum=MAX_AMPLITUDE)
    check_int("ADCBITS", settings["adc_bits"], minimum=1, maximum=32)
    check_float("FULLWELL", settings["full_well"], minimum=0.0)
    check_int("NINTS", settings["nints"], minimum=1)
    t_frame = settings["t_frame"]
    if t_frame is not None:
        check_float("TFRAME", t_frame, minimum=0.0, strict_min=True)
        if "DETNAX1" in hdr or "NAXIS1D" in hdr:
            det_time = detector_from_header(hdr).frame_time
            if not abs(t_frame - det_time) <= 1e-9 * det_time:
                raise FileFormatError(
                    f"'TFRAME' = {t_frame!r} s is not the frame time of the detector "
                    f"cards, {det_time!r} s")
    return settings


def check_truth_header(truth, *, readout=True):
    """Check every card of a truth header that :func:`compare` reads.

    ``GAIN`` (e-/DN, > 0 and at most :data:`noise.params.MAX_AMPLITUDE`), ``TFRAME``
    (s, > 0; equal to the frame time of the detector cards when the header has them,
    the cards themselves a valid detector), ``NINTS`` (>= 1; the planes of
    ``SATGROUP``/``SATREAD`` when the truth has them), ``RDNOISE`` (e- per read,
    finite, >= 0, at most ``MAX_AMPLITUDE``), ``ADCBITS`` (1 to 32), ``FULLWELL``
    (finite, >= 0) -- integer cards integers, number cards numbers (not
    ``T``/``F``) -- and, with ``readout``, the MULTIACCUM cards ``NGROUPS`` ... that
    :func:`scenesim.io.header.readout_from_header` reads, which must give at least
    two resultants.

    Parameters
    ----------
    truth : dict
        From :func:`scenesim.io.exposure.read_truth`.
    readout : bool, keyword-only
        Also check the readout cards (the read times come from them when no exposure
        is given).

    Returns
    -------
    dict
        :func:`scenesim.io.header.exposure_settings` of the header.

    Raises
    ------
    noise.errors.FileFormatError or noise.errors.ParameterError
        One line naming the card and its value (:func:`compare_files` adds the file).
    """
    hdr = truth["header"]
    settings = _check_cards(hdr)
    nints = settings["nints"]
    for name in ("SATGROUP", "SATREAD"):
        sat = truth.get(name)
        if sat is not None and np.ndim(sat) == 3 and np.shape(sat)[0] != nints:
            raise FileFormatError(f"'NINTS' = {nints} but {name} has "
                                  f"{np.shape(sat)[0]} integrations")
    try:
        rn = exposure_read_noise(hdr, default=None)
    except (TypeError, ValueError) as exc:
        raise FileFormatError(f"'RDNOISE' = {hdr.get('RDNOISE')!r} is not a number "
                              f"or a list of numbers") from exc
    if rn is not None:
        check_float("RDNOISE", rn, minimum=0.0, maximum=MAX_AMPLITUDE)
    if readout and "NGROUPS" in hdr and settings["t_frame"] is not None:
        try:
            ro = readout_from_header(hdr)
        except (TypeError, ValueError) as exc:       # FileFormatError: passed on
            if isinstance(exc, FileFormatError):
                raise
            raise FileFormatError(f"a readout card has a value of the wrong type: "
                                  f"{exc}") from exc
        if ro.ngroups < 2:
            raise FileFormatError(f"'NGROUPS' = {ro.ngroups}: a slope needs at least "
                                  f"2 resultants")
    return settings


def _named(what, path, exc):
    """``exc`` as a FileFormatError naming ``what`` ``path`` (if it does not yet)."""
    msg = str(exc)
    if path in msg:
        return FileFormatError(msg)
    return FileFormatError(f"{what} {path!r}: {msg}")


#: Header cards an exposure and its truth file share, checked by :func:`compare_files`
#: (with ``exposure``): the detector and window, the clock, the readout and the seed.
SAME_EXPOSURE_CARDS = ("DETECTOR", "DETNAX1", "DETNAX2", "NOUTPUTS", "SUBSTRT1",
                       "SUBSTRT2", "SUBSIZE1", "SUBSIZE2", "PIXDWELL", "NROH", "NFOH",
                       "TFRAME", "NGROUPS", "NFRAMES", "GROUPGAP", "DROPFRM1", "READPATT",
                       "RESETMD", "SEED", "SEEDENT")


#: Cards a slope file carries from its exposure (scenesim's fit files, a JWST rate
#: file through the uncal, a Roman L2's exposure metadata: :func:`fit_header`) that
#: must equal the truth's.
SAME_RUN_CARDS = ("NINTS", "NGROUPS", "NFRAMES", "GROUPGAP", "READPATT", "TFRAME",
                  "SEED", "SEEDENT", "SCENEID")


#: Cards the file a pipeline makes the slope file from (a JWST uncal, a Roman L1)
#: must share with the truth, checked before the pipeline runs
#: (:func:`check_compare_inputs` with ``source``): those of :data:`SAME_RUN_CARDS`
#: and the gain the truth's e- and the input's DN are related by.
SAME_SOURCE_CARDS = SAME_RUN_CARDS + ("GAIN",)


def _check_same_run(fit_hdr, truth_hdr, fit_path, truth_path, *, what="slope file",
                    cards=SAME_RUN_CARDS):
    """Raise unless the slope file (or another file ``what`` of the run) and the
    truth describe the same exposure: every card of ``cards`` both carry agrees
    (``TFRAME`` and ``GAIN`` to 1e-9; a JWST ``READPATT = 'ANY'`` stands for any
    pattern of scenesim's own, whose name is in ``SSREADPT``).  The message names
    both files and both values."""
    for key in cards:
        if key not in fit_hdr or key not in truth_hdr:
            continue
        mine, theirs = fit_hdr[key], truth_hdr[key]
        if key == "READPATT" and str(mine).strip().upper() == "ANY":
            mine = fit_hdr.get("SSREADPT", theirs)
        if key in ("TFRAME", "GAIN"):
            try:
                same = math.isclose(float(mine), float(theirs), rel_tol=1e-9)
            except (TypeError, ValueError):
                same = False
        else:
            same = str(mine).strip() == str(theirs).strip()
        if not same:
            raise FileFormatError(
                f"{what} {fit_path!r} and truth file {truth_path!r} are not of the "
                f"same exposure: {key!r} = {mine!r} in the {what}, {theirs!r} in the "
                f"truth file")


def compare_files(fit_path, truth_path, *, plots=None, exposure=None, psf=None,
                  radius=4.0, edges=DEFAULT_EDGES, cr_sigma=10.0):
    """Compare a slope file with a truth file; see :func:`compare`.

    Parameters
    ----------
    fit_path : str or os.PathLike
        scenesim fit file or JWST rate file (layout detected from extension names).
    truth_path : str or os.PathLike
        Truth file (:func:`scenesim.io.exposure.read_truth`).
    plots : str or None, keyword-only
        Directory for PNG plots.
    exposure : str or None, keyword-only
        Exposure file, for its exact ``READS`` table (read times).
    psf, radius, edges, cr_sigma : keyword-only
        As in :func:`compare`.

    Returns
    -------
    Report
    """
    fit_path = check_path("fit_path", fit_path)
    truth_path = check_path("truth_path", truth_path)
    if exposure is not None:
        exposure = check_path("exposure", exposure)
    if plots is not None:                  # a figure never replaces a compared file
        check_plot_dir(plots, inputs=[p for p in (fit_path, truth_path, exposure)
                                      if p is not None], overwrite=True)
    truth, read_times, nints, ro = _truth_and_exposure(truth_path, exposure)
    hdr = truth["header"]
    gain = exposure_settings(hdr)["gain"]
    try:
        fit = read_slopes(fit_path, gain=gain)
        fit_hdr = fit_header(fit_path)             # FITS, or a Roman L2's cal steps
        ipc_deconvolved = header_ipc_deconvolved(fit_hdr)
        dark, note = subtracted_dark_rate(fit_hdr, exposure_settings(hdr)["t_frame"],
                                          gain)
        if fit.get("read_noise") is not None:
            check_float("RNOISE", fit["read_noise"], minimum=0.0, maximum=MAX_AMPLITUDE)
    except (FileFormatError, ParameterError) as exc:
        raise _named("slope file", fit_path, exc) from exc
    _check_same_run(fit_hdr, hdr, fit_path, truth_path)
    notes = [f"fit layout: {fit['layout']}"]
    if note:
        notes.append(note)
    if dark is not None:                       # a pipeline's dark step ran
        truth = subtract_dark(truth, dark)
    if exposure is not None:
        notes.append("read times from the exposure's READS table")
    try:
        return compare(fit, truth, read_times=read_times, nints=nints, psf=psf,
                       radius=radius, edges=edges, cr_sigma=cr_sigma, plots=plots,
                       notes=notes, readout=ro, ipc_deconvolved=ipc_deconvolved,
                       reference_corrected=_reference_corrected(fit_hdr))
    except FileFormatError as exc:            # the files do not match each other
        if fit_path in str(exc) or truth_path in str(exc):
            raise
        raise FileFormatError(f"slope file {fit_path!r} and truth file "
                              f"{truth_path!r}: {exc}") from exc


def _reference_corrected(fit_hdr):
    """Whether the slopes come from reference-corrected ramps: scenesim's fits say
    so (``REFPIX``); a pipeline's rate file, which has no such card, is taken as
    corrected (Detector1 and romancal run their reference-pixel step)."""
    try:
        value = fit_hdr.get("REFPIX") if fit_hdr is not None else None
    except AttributeError:
        value = None
    if value is None:
        return True
    return str(value).strip().lower() != "none"


def check_compare_inputs(truth_path, exposure=None, *, source=None):
    """Check a truth file (and an exposure of the same run) as :func:`compare_files`
    reads them, before a long step makes the slope file to compare (``scenesim
    pipeline --truth --exposure``).

    Parameters
    ----------
    truth_path, exposure : str or os.PathLike
    source : tuple or None, keyword-only
        ``(what, path, header, shape)`` of the file the slope file will be made from
        (``'uncal'``, ``'L1'``): its cards of :data:`SAME_SOURCE_CARDS` (those it
        carries) and its image shape ``(ny, nx)`` must be the truth's, as
        :func:`compare_files` would find them in the slope file after the run.

    Raises
    ------
    noise.errors.FileFormatError, noise.errors.ParameterError
        Naming the file: not a truth file (another kind of scenesim file, a missing
        card), an exposure of another run, or a ``source`` of another exposure.
    """
    truth_path = check_path("truth_path", truth_path)
    if exposure is not None:
        exposure = check_path("exposure", exposure)
    truth = _truth_and_exposure(truth_path, exposure)[0]
    if source is None:
        return
    what, path, header, shape = source
    path = os.fspath(path)
    _check_same_run(header, truth["header"], path, truth_path, what=what,
                    cards=SAME_SOURCE_CARDS)
    rate = truth.get("RATE_IPC", truth.get("RATE"))
    if rate is not None and tuple(np.shape(rate)) != tuple(shape):
        ny, nx = np.shape(rate)
        raise FileFormatError(
            f"{what} {path!r} and truth file {truth_path!r} are not of the same "
            f"exposure: the {what} is {shape[0]} x {shape[1]} pixels, the truth file "
            f"{ny} x {nx}")


def _truth_and_exposure(truth_path, exposure):
    """``(truth, read_times, nints, readout)`` of a comparison: the truth file read
    and its header checked, and with an ``exposure`` its read times (None without),
    after checking that it is the truth's exposure.  Errors name the file."""
    truth = read_truth(truth_path)
    try:
        settings = check_truth_header(truth, readout=exposure is None)
    except (FileFormatError, ParameterError) as exc:
        raise _named("truth file", truth_path, exc) from exc
    if exposure is None:
        return truth, None, None, None
    hdr = truth["header"]
    try:
        ehdr, reads = read_exposure_header(exposure)
        esettings = _check_cards(ehdr)
        if esettings["nints"] != settings["nints"]:
            raise FileFormatError(
                f"'NINTS' = {esettings['nints']} but the truth file has "
                f"{settings['nints']}: not the same exposure")
        for key in SAME_EXPOSURE_CARDS:      # the truth records them too
            if key in ehdr and key in hdr and ehdr[key] != hdr[key]:
                raise FileFormatError(
                    f"{key!r} = {ehdr[key]!r} but the truth file has {hdr[key]!r}: "
                    f"not the same exposure")
        t_frame = esettings["t_frame"]
        if t_frame is None:
            raise FileFormatError("lacks header keyword 'TFRAME'")
        ro = readout_from_table(ehdr, reads)
        if ro.ngroups < 2:             # as the truth's own readout is checked
            raise FileFormatError(f"'NGROUPS' = {ro.ngroups}: a slope needs at least "
                                  f"2 resultants")
        read_times = ro.read_times(t_frame)
        check_read_times(read_times)
    except (FileFormatError, ParameterError) as exc:
        raise _named("exposure", exposure, exc) from exc
    return truth, read_times, ro.nints, ro


def _undefined(value):
    """True for a table value a bin cannot give (NaN)."""
    return isinstance(value, (float, np.floating)) and value != value
