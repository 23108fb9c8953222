"""Aperture photometry of the injected sources on a slope image.

Photometry (photutils): circular apertures of radius ``radius`` (default 4 px) at the
``SOURCES`` positions on the slope image, minus the median of an annulus
(``2 radius`` to ``3 radius``) times the aperture area, divided by the encircled
energy ``scenesim.sky.psf.encircled_energy(psf, radius)`` when the PSF is known (argument
``psf``, else the PSF the truth header records (``PSFFWHM``: Gaussian, ``PSFAIRY``:
Airy; :func:`scenesim.io.header.header_psf`), else no correction and
a note).  The ratio measured / injected flux is reported per source, the injected
flux being what the array collected (``flux_on_array``, the QE flat in, when the
catalogue has it; a variable source at its light curve's mean over the
integrations, which ``compare`` takes from the truth's ``LCINTS``), for sources
whose annulus lies fully on the array, whose flux exceeds 10 times the aperture
noise ``sqrt(sum V_rep)`` and whose aperture holds no unmeasured (DO_NOT_USE)
pixel (those are left out, with a note).  The median ratio's standard error is
``1.2533 std / sqrt(n)`` (the asymptotic efficiency of the median of a normal sample).

"""

import math

import numpy as np

from scenesim.sky.psf import encircled_energy

__all__ = ['source_photometry', 'annulus_medians']


_MEDIAN_EFF = 1.2533  # sqrt(pi/2): std of the median / (std / sqrt(n)) for a normal


def annulus_medians(image, annuli, bad):
    """Median of the finite, not ``bad`` pixels whose centres fall in each annulus
    (NaN where none do): photutils' ``ApertureStats(image, annuli, mask=bad).median``
    from the same 'center' masks, without the table metadata (the versions of
    photutils' optional dependencies, imported to be read: ~0.35-0.5 s per process)."""
    out = np.full(len(annuli), np.nan)
    for k, m in enumerate(annuli.to_mask(method="center")):
        vals = m.get_values(image, mask=bad)
        vals = vals[np.isfinite(vals)]
        if vals.size:
            out[k] = np.median(vals)
    return out


def source_photometry(slope, var, bad, sources, psf, radius, notes):
    # photutils is imported here, not at the top (~0.7 s; see scenesim.sky.psf)
    from photutils.aperture import CircularAnnulus, CircularAperture
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
    # the aperture's own sums: aperture_photometry adds to them a table whose metadata
    # (the versions of photutils' optional dependencies) cost ~0.35 s per process
    raw = np.asarray(ap.do_photometry(img, method="exact")[0], dtype=float)
    vsum = np.asarray(ap.do_photometry(vimg, method="exact")[0], dtype=float)
    bkg = annulus_medians(slope, ann, bad)
    measured = (raw - bkg * ap.area) / ee
    noise = np.sqrt(np.maximum(vsum, 0.0)) / ee
    # a source whose aperture holds an unmeasured pixel (DO_NOT_USE: a saturated
    # core) would count it as 0 e-/s: left out, and said (a probe's saturated star
    # read 0.32 of its flux into the median)
    holed = np.asarray(ap.do_photometry(np.asarray(bad, dtype=float),
                                        method="exact")[0], dtype=float) > 0
    if holed.any():
        notes.append(f"photometry: {int(holed.sum())} source(s) left out: unmeasured "
                     f"(DO_NOT_USE) pixels in the aperture")
    # what the array collected (the QE flat in), when the catalogue says
    inj = (np.asarray(sources["flux_on_array"], dtype=float) if "flux_on_array" in
           sources.colnames else flux)[inside]
    bright = (inj > 10.0 * noise) & ~holed
    if not bright.any():
        notes.append("photometry: no usable source (brighter than 10x its aperture "
                     "noise, every aperture pixel measured)")
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
