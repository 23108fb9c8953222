"""The truth of a variable source: its rate in each integration (``LCINTS``), and
``RATE`` as the mean over the spans the slopes measure.

Before (found by a probe, 2026-11-27), the truth held one ``RATE``, the light curve
averaged over the whole exposure, resets and gaps included, and nothing per
integration: the quantity a time-series user fits (one slope per integration) had
no truth.  A step light curve makes every expected value a closed form.
"""

import numpy as np
import pytest
from astropy.io import fits

from scenesim.engine import EngineOptions
from scenesim.run import build_engine, run_scene
from scenesim.scene import parse_scene


def _scene(tmp_path, t_on, *, reset="rolling", ngroups=4, after=0.5, const=100.0):
    return parse_scene({
        "seed": 2, "detector": {"preset": "H2RG", "naxis1": 32, "naxis2": 32},
        "noise": {"preset": "none"},
        "readout": {"pattern": "RAPID", "ngroups": ngroups, "nints": 3, "reset": reset},
        "sources": {"psf": {"kind": "gaussian", "fwhm": 2.0},
                    "stars": [{"x": 15.3, "y": 16.1, "flux": 1e4, "light_curve": "s"},
                              {"x": 8.0, "y": 8.0, "flux": const}],
                    "light_curves": {"s": {"kind": "step", "t_on": t_on,
                                           "after": after}}},
        "output": {"path": str(tmp_path / "e.fits"), "truth": True, "fit": ""}})


def _step_mean(t1, t2, t_on, after):
    """Closed-form mean of a step from 1 to ``after`` at ``t_on`` over [t1, t2] (the
    value at t1 where t1 == t2: the first pixel after a global reset, read at once)."""
    width = t2 - t1
    value = np.where(t1 < t_on, 1.0, after)
    return np.where(width > 0, step_integral(t1, t2, t_on, 1.0, after)
                    / np.where(width > 0, width, 1.0), value)


def step_integral(a, b, t_on, before, after):
    return (before * (np.minimum(b, t_on) - np.minimum(a, t_on))
            + after * (np.maximum(b, t_on) - np.maximum(a, t_on)))


@pytest.mark.parametrize("reset, ngroups", [("rolling", 4), ("global", 4),
                                            ("rolling", 1), ("global", 1)])
def test_each_integration_has_its_light_curve_mean_and_rate_their_mean(
        tmp_path, reset, ngroups):
    # RAPID x ngroups, 3 integrations: integration i's reset frame starts at T_i =
    # (1 + ngroups) i t_frame.  A pixel of clock offset t_p (its sample's time into a
    # frame, Detector.pixel_time) is read at T_i + (k + 1) t_frame + t_p, for a
    # rolling reset and a global one alike (the global reset is at T_i + t_frame,
    # docs/CONVENTIONS.md); its slope spans its first to last read, or, with one
    # group, its reset (rolling: T_i + t_p; global: T_i + t_frame) to its read.  The
    # step (1 -> 0.5) lands halfway through integration 1's span.  Every expected
    # value is a closed form of these windows: RATE per pixel (the mean of the three
    # integrations' means), LCINTS's windows at the brightest pixel, and its means
    # weighted by the pixels' rates.  (A probe found the global reset's windows one
    # frame early, and every pixel's offset left out: a star at row 40 of a 64-row
    # frame had read 12500 e-/s where its pixels' slopes summed to 28000.)
    engine, _ = build_engine(_scene(tmp_path, 1.0, reset=reset, ngroups=ngroups))
    det = engine.detector
    tf = det.frame_time
    T = np.arange(3) * (1 + ngroups) * tf
    t_on = T[1] + tf + 0.5 * (ngroups - 1 if ngroups > 1 else 1) * tf
    scene = _scene(tmp_path, t_on, reset=reset, ngroups=ngroups)
    # the variable star's rate per pixel at relative flux 1: alone and constant
    alone = _scene(tmp_path, t_on, reset=reset, ngroups=ngroups, after=1.0, const=0.0)
    run_scene(alone, progress=False, options=EngineOptions(threads=1))
    with fits.open(tmp_path / "e_truth.fits") as t:
        weight = t["RATE"].data.astype(float)
    run_scene(scene, progress=False, options=EngineOptions(threads=1), overwrite=True)
    with fits.open(tmp_path / "e_truth.fits") as t:
        lc = t["LCINTS"].data
        src = t["SOURCES"].data
        rate = t["RATE"].data.astype(float)
        nextend = t[0].header["NEXTEND"]
        n_hdu = len(t) - 1
    assert nextend == n_hdu
    row = int(np.flatnonzero(src["light_curve"] == "s")[0])
    const = float(src["flux_on_array"][1 - row])
    on = float(src["flux_on_array"][row])
    stamp = weight > 0
    tp = det.pixel_time()[:, :, None] + np.zeros(3)          # (ny, nx, nints)
    end = T + (ngroups * tf) + tp
    if ngroups > 1:
        start = T + tf + tp
    else:
        start = T + tp + 0.0 * tp if reset == "rolling" else T + tf + 0.0 * tp
    means = _step_mean(start, end, t_on, 0.5)                 # (ny, nx, nints)
    # RATE less the constant star's pixels (its own rendering, flux 100)
    from scenesim.sky.psf import GaussianPSF, render_point_sources
    const_img, _ = render_point_sources(det.shape, [8.0], [8.0], [100.0],
                                        GaussianPSF(fwhm=2.0),
                                        blind=det.reference_mask())
    expected = weight * means.mean(axis=2) + const_img
    np.testing.assert_allclose(rate, expected, rtol=1e-5, atol=1e-6)   # float32 file
    assert rate.sum() == pytest.approx(const + on * float(
        np.sum(weight[stamp] * means[stamp].mean(axis=1)) / weight[stamp].sum()),
        rel=1e-5)
    assert np.all(lc["SOURCE"] == row)
    np.testing.assert_array_equal(lc["INTEGRATION"], [0, 1, 2])
    peak = np.unravel_index(np.argmax(np.where(stamp, weight, 0)), det.shape)
    np.testing.assert_allclose(lc["T_START"], start[peak], rtol=1e-12)
    np.testing.assert_allclose(lc["T_END"], end[peak], rtol=1e-12)
    w = weight[stamp] / weight[stamp].sum()
    lc_mean = w @ means[stamp]                                # rate-weighted, (nints,)
    np.testing.assert_allclose(lc["LC_MEAN"], lc_mean, rtol=1e-6)
    np.testing.assert_allclose(lc["FLUX"], on * lc_mean, rtol=1e-6)
    # integration 0 before the step, 2 after it, 1 across it
    np.testing.assert_allclose(lc["LC_MEAN"][[0, 2]], [1.0, 0.5], rtol=1e-12)
    assert 0.5 < lc["LC_MEAN"][1] < 1.0


@pytest.mark.parametrize("reset", ["rolling", "global"])
def test_rate_is_what_the_noise_free_slopes_of_averaged_groups_measure(tmp_path, reset):
    # Groups of 4 frames (1 dropped between): a step inside the first group of
    # integration 1 weighs each of its reads, not a box between the groups' mean
    # times (a probe: box mean 1.0 where the noise-free slopes read 0.96).  The
    # truth's RATE must be the mean over the integrations of the noise-free CDS
    # slopes (charge without shot noise, save_charge), pixel by pixel, to float32
    # precision of the charge (1e-5 relative here).
    from astropy.table import Table
    tf = build_engine(_scene(tmp_path, 1.0, reset=reset))[0].detector.frame_time
    ro = {"nframes": 4, "ngroups": 3, "groupgap": 1, "nints": 2, "reset": reset}
    T1 = (1 + 4 * 3 + 2) * tf                       # integration 1's reset frame
    scene = parse_scene({
        "seed": 2, "detector": {"preset": "H2RG", "naxis1": 32, "naxis2": 32},
        "noise": {"preset": "none"}, "readout": ro,
        "sources": {"psf": {"kind": "gaussian", "fwhm": 2.0},
                    "stars": [{"x": 15.3, "y": 16.1, "flux": 1e5, "light_curve": "s"}],
                    "light_curves": {"s": {"kind": "step", "t_on": T1 + 2.5 * tf,
                                           "after": 0.2}}},
        "output": {"path": str(tmp_path / "m.fits"), "truth": True, "fit": "",
                   "save_charge": True}})
    run_scene(scene, progress=False, options=EngineOptions(threads=1, shot_noise=False))
    with fits.open(tmp_path / "m_truth.fits") as t:
        rate = t["RATE"].data.astype(float)
        charge = t["CHARGE"].data.astype(float)              # (nints, ngroups, y, x)
        reads = Table(t["READS"].data)
    tbar = np.asarray(reads["TMEAN"], float)
    # (a global reset's reads come t_p into their frames: the same shift of both
    # groups' mean times, so their difference is the table's)
    slopes = (charge[:, -1] - charge[:, 0]) / (tbar[-1] - tbar[0])
    lit = rate > 1e-3 * rate.max()
    np.testing.assert_allclose(rate[lit], slopes.mean(axis=0)[lit], rtol=1e-4)
    # and the step moved it: the box mean between the groups' mean times is not it
    assert not np.allclose(rate[lit], slopes[0][lit], rtol=1e-2)


def test_a_scene_without_variable_sources_has_no_light_curve_table(tmp_path):
    scene = _scene(tmp_path, 1.0)
    scene = scene.replace(sources=parse_scene({
        "seed": 1, "readout": {"pattern": "RAPID", "ngroups": 2},
        "sources": {"stars": [{"x": 8.0, "y": 8.0, "flux": 100.0}]}}).sources)
    run_scene(scene, progress=False, options=EngineOptions(threads=1))
    with fits.open(tmp_path / "e_truth.fits") as t:
        assert "LCINTS" not in t and t[0].header["NEXTEND"] == len(t) - 1


def test_compare_measures_a_variable_source_against_its_mean_over_the_integrations(
        tmp_path):
    # noise-free: the exposure's slope of the step star is its LCINTS mean (0.75 of
    # its flux), and so is compare's photometry (it took the constant flux: 0.75)
    from scenesim.validate.compare import compare_files
    engine, _ = build_engine(_scene(tmp_path, 1.0))
    tf = engine.detector.frame_time
    scene = _scene(tmp_path, 5 * tf + 2.5 * tf)
    run_scene(scene.replace(output=scene.output.__class__(
        **{**scene.output.__dict__, "fit": "gls", "refpix": "none"})), progress=False,
        options=EngineOptions(threads=1))
    rep = compare_files(tmp_path / "e_gls.fits", tmp_path / "e_truth.fits")
    assert any("LCINTS" in n for n in rep.notes), rep.notes
    with fits.open(tmp_path / "e_truth.fits") as t:
        expected = float(np.mean(t["LCINTS"].data["FLUX"]))
    star = {round(s["x"], 1): s for s in rep.photometry["sources"]}[15.3]
    assert star["flux"] == pytest.approx(expected, rel=1e-9)
    # measured against it: within 10 % (the GLS weighs the integrations by their
    # inverse Poisson variance, the fainter ones more: 0.92 here; against the
    # constant flux it read 0.69)
    assert abs(star["ratio"] - 1) < 0.1, star["ratio"]
