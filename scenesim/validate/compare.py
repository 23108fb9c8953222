"""Compare fitted slopes with the truth injected by the simulator.

What is measured
----------------
Pixels are binned by their true rate ``RATE_IPC`` (e-/s, after IPC and flat: what a
linear ramp fit should recover; ``RATE`` if absent), in log bins
(:data:`DEFAULT_EDGES`).  Reference pixels are left out; the statistics use the pixels
not flagged ``DO_NOT_USE``.  For each bin, with ``r = fit - truth``:

* ``bias_rep = mean(r / sqrt(V_rep))`` and ``chi2_rep = mean(r^2 / V_rep)``, with
  ``V_rep`` the variance the fitter reported: ``chi2_rep`` ~ 1 when the reported errors
  are right, ``bias_rep`` ~ 0 when the fit is unbiased (standard error
  ``1/sqrt(n)``);
* ``bias_opt = mean(r / sqrt(V_opt))`` and ``std_opt = std(r / sqrt(V_opt))`` with
  ``V_opt = optimal_variance(truth, read_times, read_noise) / nints``, the minimum
  variance of an unbiased linear slope estimate for that readout (Brandt 2024, PASP
  136, 045004, eqs. 28-29; integrations are independent, so their optimal combination
  divides it by ``nints``).  ``std_opt`` = 1 for an optimal fitter; an equal-weight
  fitter reaches ``sqrt(V_ols / V_opt)`` (``ols_ratio``, the bin mean, from
  :func:`scenesim.rampfit.fit.ols_variance`).  Its standard error is about
  ``std_opt / sqrt(2 n)``;
* ``chi2_fit``: mean reported ``CHI2`` (when the file has it);
* ``frac_flagged``: fraction of the bin's regular pixels with any DQ bit set.

Jumps: a pixel is *hit* when a cosmic ray that a read saw (``SEEN``) deposited more
than ``cr_sigma`` (10) times the noise of a difference of two reads,
``sqrt(2) * read_noise``, *inside* the pixel's usable ramp of an integration: after
the first read of the first resultant and not after the last read of the last
unsaturated resultant (truth ``SATGROUP``), in clock time (frame slot ``s`` of the
readout, ``s * TFRAME + t_pix`` with the pixel's read time in the frame from the
detector cards of the truth header).  A deposit before the first read is in every
read (an offset, not a jump: no ramp-based method can see it; on the cosmic-ray
scene these were the 1.3 % of "missed" hits), and one after the last usable read in
none.  Without detector cards or readout every seen deposit counts (a note says so).
Completeness = fraction of hit pixels flagged ``JUMP_DET``; false-positive rate =
fraction of *clean* pixels flagged ``JUMP_DET``: pixels without any deposit (of any
size, seen or not) and, when the truth header says IPC was applied, without a
deposit among their 8 neighbours (the 3 x 3 IPC kernel moves a fraction of a
neighbour's charge, hence of its jump, into them).

Photometry (photutils): circular apertures of radius ``radius`` (default 4 px) at the
``SOURCES`` positions on the slope image, minus the median of an annulus
(``2 radius`` to ``3 radius``) times the aperture area, divided by the encircled
energy ``scenesim.sky.psf.encircled_energy(psf, radius)`` when the PSF is known (argument
``psf``, else the PSF the truth header records (``PSFFWHM``: Gaussian, ``PSFAIRY``:
Airy; :func:`scenesim.io.header.header_psf`), else no correction and
a note).  The ratio measured / injected ``flux`` is reported per source, for sources
whose annulus lies fully on the array and whose flux exceeds 10 times the aperture
noise ``sqrt(sum V_rep)``.  The median ratio's standard error is
``1.2533 std / sqrt(n)`` (the asymptotic efficiency of the median of a normal sample).

Fit files: the scenesim layout (:func:`scenesim.rampfit.fit.read_fit`, e-/s) or a JWST rate
file (``SCI`` in DN/s, ``DQ``, ``VAR_POISSON`` and ``VAR_RNOISE`` in (DN/s)^2, or
``ERR``), converted to e- with the truth header's ``GAIN`` (e-/DN).  The layout is
detected from the extension names.

Read times: from the exposure's ``READS`` table when the exposure is given (exact for
any readout), else a MULTIACCUM rebuilt from the truth header cards ``NFRAMES``,
``NGROUPS``, ``GROUPGAP``, ``DROPFRM1``, ``TFRAME`` (exact for MULTIACCUM patterns
only; a note says so).  A global reset shifts all read times of a pixel together,
which leaves ``V_opt`` unchanged, so the rolling-reset times are used for both.
"""

import math
import os
from dataclasses import dataclass, field

import numpy as np
from astropy.io import fits
from astropy.table import Table

from noise.clock import detector_from_header, frame_slot
from noise.errors import FileFormatError, ParameterError
from noise.fitsio import atomic_path

from scenesim.io.header import (exposure_read_noise, header_psf, readout_from_header,
                                readout_from_table)
from scenesim.detector.dq import DO_NOT_USE, JUMP_DET, REFERENCE_PIXEL
from scenesim.io.fitfile import fit_arrays, read_slopes
from scenesim.rampfit import ols_variance, optimal_variance

__all__ = ["DEFAULT_EDGES", "Report", "compare", "compare_files"]

#: Default flux-bin edges, e-/s (true rate ``RATE_IPC``).
DEFAULT_EDGES = (0.0, 0.01, 0.1, 1.0, 10.0, 100.0, 1e3, 1e4, np.inf)

_MEDIAN_EFF = 1.2533  # sqrt(pi/2): std of the median / (std / sqrt(n)) for a normal


# ---------------------------------------------------------------------- report
@dataclass(frozen=True)
class Report:
    """Result of :func:`compare`.

    Attributes
    ----------
    rows : list of dict
        One dict per flux bin: ``lo``, ``hi`` (e-/s), ``n_regular`` (regular pixels),
        ``n`` (of which not ``DO_NOT_USE``), ``bias_rep``, ``chi2_rep``, ``bias_opt``,
        ``std_opt``, ``ols_ratio``, ``chi2_fit``, ``frac_flagged`` (NaN when empty).
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
                ("bias_opt", "{:>9.3f}"), ("std_opt", "{:>8.3f}"),
                ("ols_ratio", "{:>9.3f}"), ("chi2_fit", "{:>9.3f}"),
                ("frac_flagged", "{:>12.4f}")]
        head = " ".join(f"{name:>{len(fmt.format(1) if 'd' in fmt else fmt.format(1.0))}}"
                        for name, fmt in cols)
        lines = ["Slopes vs truth per true-rate bin (e-/s)", head]
        for row in self.rows:
            lines.append(" ".join(fmt.format(row[name]) for name, fmt in cols))
        j = self.jumps
        if j:
            lines += ["", f"Jumps (hit: CR charge > {j['threshold_e']:.3g} e- inside a "
                      f"ramp): "
                      f"completeness {j['completeness']:.4f} of {j['n_hit']} hit pixels; "
                      f"false-positive rate {j['false_positive']:.3g} of {j['n_clean']} "
                      f"clean pixels"]
        p = self.photometry
        if p and p.get("n", 0):
            lines += ["", f"Aperture photometry (r = {p['radius']:g} px, aperture "
                      f"correction {p['aperture_correction']:.4f}): median measured/"
                      f"injected = {p['median_ratio']:.4f} +- "
                      f"{p['median_ratio_err']:.4f} over {p['n']} sources",
                      f"{'x':>9} {'y':>9} {'flux':>11} {'measured':>11} {'ratio':>8}"]
            for s in p["sources"]:
                lines.append(f"{s['x']:>9.2f} {s['y']:>9.2f} {s['flux']:>11.4g} "
                             f"{s['measured']:>11.4g} {s['ratio']:>8.4f}")
        if self.plots:
            lines += ["", "Plots: " + ", ".join(self.plots)]
        if self.notes:
            lines += ["", "Notes:"] + [f"- {n}" for n in self.notes]
        return "\n".join(lines)


def _readout_from_exposure(path):
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileFormatError(f"'exposure': file {path!r} does not exist")
    with fits.open(path, memmap=True) as hdul:
        names = [h.name for h in hdul]
        if "READS" not in names:
            raise FileFormatError(
                f"exposure {path!r} has no 'READS' extension (found {names})")
        hdr = hdul[0].header
        return readout_from_table(hdr, Table.read(hdul["READS"])), hdr


# ---------------------------------------------------------------------- analysis
def _bin_rows(fit, rate, var_opt, var_ols, edges, use_mask, regular):
    res = fit["slope"] - rate
    var = fit["var"]
    good = use_mask & np.isfinite(var) & (var > 0) & (var_opt > 0)
    rows = []
    idx = np.digitize(rate, edges[1:-1], right=False)  # bin k: edges[k] <= r < edges[k+1]
    for k in range(len(edges) - 1):
        inbin = idx == k
        reg = regular & inbin
        sel = good & inbin
        n = int(sel.sum())
        row = {"lo": float(edges[k]), "hi": float(edges[k + 1]),
               "n_regular": int(reg.sum()), "n": n}
        nan = float("nan")
        if n:
            z_rep = res[sel] / np.sqrt(var[sel])
            z_opt = res[sel] / np.sqrt(var_opt[sel])
            row.update(bias_rep=float(z_rep.mean()), chi2_rep=float(np.mean(z_rep ** 2)),
                       bias_opt=float(z_opt.mean()),
                       std_opt=float(z_opt.std(ddof=1)) if n > 1 else nan,
                       ols_ratio=float(np.mean(np.sqrt(var_ols[sel] / var_opt[sel]))),
                       chi2_fit=(float(fit["chi2"][sel].mean()) if fit["chi2"] is not None
                                 else nan))
        else:
            row.update(bias_rep=nan, chi2_rep=nan, bias_opt=nan, std_opt=nan,
                       ols_ratio=nan, chi2_fit=nan)
        row["frac_flagged"] = (float(np.mean(fit["dq"][reg] != 0)) if row["n_regular"]
                               else nan)
        rows.append(row)
    return rows


def _ramp_windows(truth, readout, t_frame):
    """Clock-time bounds of every pixel's usable ramp in each integration.

    Returns ``(t_first, t_last)``, functions of pixel ``(y, x)`` arrays giving
    (nints, n) clock times (s) of the first read of the first resultant and of the
    last read of the last unsaturated resultant (``SATGROUP``; NaN when fewer than
    two resultants are unsaturated), or None when the truth lacks the detector
    cards.  Clock time of frame slot ``s``: ``s * t_frame + t_pix``.
    """
    try:
        det = detector_from_header(truth["header"])
    except (FileFormatError, ParameterError, KeyError, ValueError):
        return None
    tpix = det.pixel_time()
    if tpix.shape != truth.get("RATE", np.zeros(det.shape)).shape:
        return None
    nints = readout.nints
    nreads = readout.nreads
    first_read = readout.resultants[0][0]
    last_reads = np.array([r[-1] for r in readout.resultants])
    satg = truth.get("SATGROUP")
    if satg is not None:
        satg = np.asarray(satg)
        if satg.ndim == 2:
            satg = satg[None]
        if satg.shape != (nints,) + det.shape:
            satg = None
    ng = len(readout.resultants)

    def bounds(y, x):
        i = np.arange(nints)[:, None]
        tp = tpix[y, x][None, :]
        t0 = frame_slot(i, first_read, nreads) * t_frame + tp
        g_end = np.full((nints, y.size), ng - 1)
        if satg is not None:
            s = satg[:, y, x].astype(np.int64)
            g_end = np.where(s >= 0, s - 1, ng - 1)
        t1 = frame_slot(i, last_reads[np.clip(g_end, 0, ng - 1)], nreads) * t_frame + tp
        return t0, np.where(g_end >= 1, t1, np.nan)

    return bounds


def _jump_stats(dq, crs, shape, read_noise, cr_sigma, regular, *, windows=None,
                ipc=False):
    ny, nx = shape
    thr = cr_sigma * math.sqrt(2.0) * read_noise
    x = np.asarray(crs["X"], dtype=np.int64)
    y = np.asarray(crs["Y"], dtype=np.int64)
    q = np.asarray(crs["CHARGE"], dtype=np.float64)
    seen = np.asarray(crs["SEEN"], dtype=bool)
    on = (x >= 0) & (x < nx) & (y >= 0) & (y < ny)
    flat = y[on] * nx + x[on]
    any_dep = np.bincount(flat, minlength=ny * nx).reshape(shape) > 0
    big = on & seen & (q > thr)
    if windows is not None and "TIME" in crs.colnames:
        t = np.asarray(crs["TIME"], dtype=np.float64)[big]
        t0, t1 = windows(y[big], x[big])
        with np.errstate(invalid="ignore"):
            inside = ((t[None] > t0) & (t[None] <= t1)).any(axis=0)
        idx = np.flatnonzero(big)
        big[idx[~inside]] = False
    hit = np.bincount(y[big] * nx + x[big], minlength=ny * nx).reshape(shape) > 0
    flagged = (dq & JUMP_DET) != 0
    hit &= regular
    near = any_dep
    if ipc:                     # the 3 x 3 IPC kernel moves charge to the 8 neighbours
        pad = np.pad(any_dep, 1)
        near = np.zeros_like(any_dep)
        for dy in range(3):
            for dx in range(3):
                near |= pad[dy:dy + ny, dx:dx + nx]
    clean = regular & ~near
    n_hit, n_clean = int(hit.sum()), int(clean.sum())
    return {"n_hit": n_hit,
            "completeness": float(flagged[hit].mean()) if n_hit else float("nan"),
            "n_clean": n_clean,
            "false_positive": float(flagged[clean].mean()) if n_clean else float("nan"),
            "threshold_e": float(thr)}


def _photometry(slope, var, bad, sources, psf, radius, notes):
    from photutils.aperture import (ApertureStats, CircularAnnulus, CircularAperture,
                                    aperture_photometry)
    ny, nx = slope.shape
    r_in, r_out = 2.0 * radius, 3.0 * radius
    x = np.asarray(sources["x"], dtype=float)
    y = np.asarray(sources["y"], dtype=float)
    flux = np.asarray(sources["flux"], dtype=float)
    inside = ((x - r_out >= -0.5) & (x + r_out <= nx - 0.5)
              & (y - r_out >= -0.5) & (y + r_out <= ny - 0.5))
    if "frac_on_array" in sources.colnames:
        inside &= np.asarray(sources["frac_on_array"], dtype=float) >= 0.999
    out = {"radius": float(radius), "aperture_correction": float("nan"), "n": 0,
           "sources": [], "median_ratio": float("nan"), "median_ratio_err": float("nan")}
    if psf is not None:
        from scenesim.sky.psf import encircled_energy
        ee = float(encircled_energy(psf, radius))
        out["aperture_correction"] = ee
    else:
        ee = 1.0
        notes.append("photometry: PSF unknown (no 'psf' argument, no PSFFWHM or PSFAIRY "
                     "in the truth header): no aperture correction applied")
    if not inside.any():
        notes.append("photometry: no source fully on the array")
        return out
    pos = np.column_stack([x[inside], y[inside]])
    img = np.where(bad, 0.0, slope)
    vimg = np.where(bad | ~np.isfinite(var), 0.0, var)
    ap = CircularAperture(pos, r=radius)
    ann = CircularAnnulus(pos, r_in=r_in, r_out=r_out)
    raw = np.asarray(aperture_photometry(img, ap, method="exact")["aperture_sum"])
    vsum = np.asarray(aperture_photometry(vimg, ap, method="exact")["aperture_sum"])
    bkg = np.asarray(ApertureStats(slope, ann, mask=bad).median, dtype=float)
    measured = (raw - bkg * ap.area) / ee
    noise = np.sqrt(np.maximum(vsum, 0.0)) / ee
    inj = flux[inside]
    bright = inj > 10.0 * noise
    if not bright.any():
        notes.append("photometry: no source brighter than 10x its aperture noise")
        return out
    ratio = measured[bright] / inj[bright]
    out["sources"] = [{"x": float(a), "y": float(b), "flux": float(f), "measured": float(m),
                       "noise": float(s), "ratio": float(r)}
                      for a, b, f, m, s, r in zip(pos[bright, 0], pos[bright, 1],
                                                  inj[bright], measured[bright],
                                                  noise[bright], ratio)]
    n = int(ratio.size)
    out["n"] = n
    out["median_ratio"] = float(np.median(ratio))
    out["median_ratio_err"] = (float(_MEDIAN_EFF * ratio.std(ddof=1) / math.sqrt(n))
                               if n > 1 else float("nan"))
    return out


def _savefig(fig, path):
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    return path


def _plots(directory, fit, rate, var_opt, use, rows, notes):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        notes.append("plots skipped: matplotlib is not importable")
        return []
    written = []
    slope = fit["slope"]
    fig, ax = plt.subplots(figsize=(6, 5))
    finite = slope[use]
    lo, hi = (np.percentile(finite, [1, 99]) if finite.size else (0.0, 1.0))
    im = ax.imshow(slope, origin="lower", vmin=lo, vmax=hi, cmap="gray")
    fig.colorbar(im, ax=ax, label="slope (e-/s)")
    ax.set_title("Fitted slope")
    written.append(_savefig(fig, os.path.join(directory, "slope.png")))
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4))
    z = (slope - rate)[use] / np.sqrt(fit["var"][use])
    z = z[np.isfinite(z)]
    grid = np.linspace(-5, 5, 201)
    ax.hist(np.clip(z, -5, 5), bins=100, range=(-5, 5), density=True, histtype="step",
            label="(fit - truth) / sqrt(reported var)")
    ax.plot(grid, np.exp(-0.5 * grid ** 2) / math.sqrt(2 * math.pi), label="N(0, 1)")
    ax.set_yscale("log")
    ax.legend(fontsize=8)
    written.append(_savefig(fig, os.path.join(directory, "residuals.png")))
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4))
    ok = [r for r in rows if r["n"] > 1]
    centre = [math.sqrt(max(r["lo"], 1e-3) * r["hi"]) if np.isfinite(r["hi"])
              else 2 * max(r["lo"], 1e-3) for r in ok]
    ax.errorbar(centre, [r["std_opt"] for r in ok],
                yerr=[r["std_opt"] / math.sqrt(2 * r["n"]) for r in ok], fmt="o",
                label="measured std / sqrt(V_opt)")
    ax.plot(centre, [r["ols_ratio"] for r in ok], "s--", label="equal weights (OLS)")
    ax.axhline(1.0, color="k", lw=0.8, label="optimal")
    ax.set_xscale("log")
    ax.set_xlabel("true rate (e-/s)")
    ax.set_ylabel("std / sqrt(V_opt)")
    ax.legend(fontsize=8)
    written.append(_savefig(fig, os.path.join(directory, "noise_vs_flux.png")))
    plt.close(fig)
    return written


def compare(fit, truth, *, read_times=None, nints=None, read_noise=None, psf=None,
            radius=4.0, edges=DEFAULT_EDGES, cr_sigma=10.0, plots=None, notes=(),
            readout=None, ipc_deconvolved=False):
    """Compare fitted slopes with the truth.

    Parameters
    ----------
    fit : FitResult or dict
        A :class:`scenesim.rampfit.fit.FitResult`, or a dict with ``slope`` (e-/s), ``var``
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

    Returns
    -------
    Report
    """
    f = fit_arrays(fit)
    if not isinstance(truth, dict) or "header" not in truth:
        raise ParameterError("'truth' must be a dict from scenesim.io.exposure.read_truth "
                             f"(with 'header'), got {type(truth).__name__}")
    notes = list(notes)
    if "RATE_IPC" in truth:
        rate = np.asarray(truth["RATE_IPC"], dtype=np.float64)
    elif "RATE" in truth:
        rate = np.asarray(truth["RATE"], dtype=np.float64)
        notes.append("truth has no RATE_IPC: compared with RATE (before IPC and flat)")
    else:
        raise FileFormatError("truth has neither 'RATE_IPC' nor 'RATE'")
    kernel = None
    if ipc_deconvolved and "RATE_IPC" in truth:
        from scenesim.calib.prepare import header_ipc_kernel
        from scenesim.detector.ipc import undo_ipc
        kernel = header_ipc_kernel(truth["header"])
        if kernel is not None:
            # what a fit of IPC-deconvolved ramps recovers: RATE_IPC with IPC undone
            # (exact with a flat field too, which the engine applies after IPC)
            rate = undo_ipc(rate, kernel, tolerance=1e-9 * max(1.0, np.abs(rate).max()))
            notes.append("fit undid IPC (IPCDECON): compared with RATE_IPC with the "
                         "IPCKERN kernel undone")
    if rate.shape != f["slope"].shape:
        raise FileFormatError(
            f"truth rate shape {rate.shape} does not match the fit's slope shape "
            f"{f['slope'].shape}")
    edges = np.asarray(edges, dtype=float)
    if edges.ndim != 1 or edges.size < 2 or np.any(np.diff(edges) <= 0):
        raise ParameterError(f"'edges' must be >= 2 increasing values (e-/s), got {edges!r}")
    if not (np.isfinite(radius) and radius > 0):
        raise ParameterError(f"'radius' must be a finite number > 0 (pixels), got {radius!r}")
    if not (np.isfinite(cr_sigma) and cr_sigma > 0):
        raise ParameterError(f"'cr_sigma' must be a finite number > 0, got {cr_sigma!r}")
    if plots is not None and not os.path.isdir(plots):
        raise ParameterError(f"'plots' must be an existing directory or None, got {plots!r}")
    if readout is not None:
        from scenesim.detector.readout import Readout
        if not isinstance(readout, Readout):
            raise ParameterError(f"'readout' must be a scenesim.detector.readout.Readout or None, "
                                 f"got {type(readout).__name__}")
    hdr = truth["header"]
    if read_noise is None:
        read_noise = exposure_read_noise(hdr, default=None)
        if read_noise is None:
            read_noise = f["read_noise"]
        if read_noise is None:
            raise ParameterError("'read_noise' not given and neither the truth header "
                                 "(RDNOISE) nor the fit has it")
    read_noise = float(read_noise)
    if kernel is not None:        # undoing IPC amplified the white read noise
        from scenesim.detector.ipc import ipc_noise_gain
        read_noise *= ipc_noise_gain(kernel)
    if read_times is None:
        if "TFRAME" not in hdr:
            raise FileFormatError("truth header lacks 'TFRAME'; pass 'read_times' or the "
                                  "exposure file")
        if readout is None:
            readout = readout_from_header(hdr)
            notes.append("read times rebuilt as MULTIACCUM from the truth header (exact "
                         "for MULTIACCUM patterns only; pass the exposure for others)")
        read_times = readout.read_times(float(hdr["TFRAME"]))
    if nints is None:
        nints = int(hdr.get("NINTS", 1))
    if psf is None:
        psf = header_psf(hdr)

    dq = f["dq"]
    regular = (dq & np.uint32(REFERENCE_PIXEL)) == 0
    use = regular & ((dq & np.uint32(DO_NOT_USE)) == 0)
    r0 = np.clip(rate, 0.0, None)
    with np.errstate(divide="ignore", invalid="ignore"):  # rate = read noise = 0
        var_opt = np.asarray(optimal_variance(r0, read_times, read_noise)) / nints
        var_ols = np.asarray(ols_variance(r0, read_times, read_noise)) / nints
    var_opt = np.where(np.isfinite(var_opt), var_opt, 0.0)
    rows = _bin_rows(f, rate, var_opt, var_ols, edges, use, regular)

    jumps = {}
    crs = truth.get("CRS")
    if crs is not None and all(c in crs.colnames for c in ("X", "Y", "CHARGE", "SEEN")):
        windows = None
        if readout is None and "TFRAME" in hdr and "NGROUPS" in hdr:
            try:
                readout = readout_from_header(hdr)
            except FileFormatError:
                readout = None
        if readout is not None and "TFRAME" in hdr:
            windows = _ramp_windows(truth, readout, float(hdr["TFRAME"]))
        if windows is None:
            notes.append("jumps: no detector cards or readout in the truth: every seen "
                         "deposit counts as a hit, even one before the first read")
        jumps = _jump_stats(dq, crs, rate.shape, read_noise, cr_sigma, regular,
                            windows=windows, ipc=bool(hdr.get("IPC", False)))
    else:
        notes.append("jumps: truth has no CRS table with X, Y, CHARGE, SEEN: skipped")

    photometry = {}
    src = truth.get("SOURCES")
    if src is not None and len(src) and all(c in src.colnames for c in ("x", "y", "flux")):
        photometry = _photometry(f["slope"], f["var"], ~use, src, psf, float(radius),
                                 notes)
    else:
        notes.append("photometry: no sources in the truth")

    written = _plots(plots, f, rate, var_opt, use, rows, notes) if plots else []
    if plots is None:
        notes.append("plots: not requested")
    return Report(rows=rows, jumps=jumps, photometry=photometry, notes=notes,
                  plots=written)


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
    from scenesim.io.exposure import read_truth
    truth = read_truth(os.fspath(truth_path))
    hdr = truth["header"]
    gain = float(hdr["GAIN"]) if "GAIN" in hdr else None
    fit = read_slopes(fit_path, gain=gain)
    notes = [f"fit layout: {fit['layout']}"]
    ipc_deconvolved = bool(fits.getheader(os.fspath(fit_path)).get("IPCDECON", False))
    read_times = nints = ro = None
    if exposure is not None:
        ro, ehdr = _readout_from_exposure(exposure)
        if "TFRAME" not in ehdr:
            raise FileFormatError(f"exposure {exposure!r} lacks header keyword 'TFRAME'")
        read_times = ro.read_times(float(ehdr["TFRAME"]))
        nints = ro.nints
        notes.append("read times from the exposure's READS table")
    return compare(fit, truth, read_times=read_times, nints=nints, psf=psf,
                   radius=radius, edges=edges, cr_sigma=cr_sigma, plots=plots,
                   notes=notes, readout=ro, ipc_deconvolved=ipc_deconvolved)
