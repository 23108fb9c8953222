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


def _scene(tmp_path, t_on):
    return parse_scene({
        "seed": 2, "detector": {"preset": "H2RG", "naxis1": 32, "naxis2": 32},
        "noise": {"preset": "none"},
        "readout": {"pattern": "RAPID", "ngroups": 4, "nints": 3},
        "sources": {"psf": {"kind": "gaussian", "fwhm": 2.0},
                    "stars": [{"x": 15.3, "y": 16.1, "flux": 1e4, "light_curve": "s"},
                              {"x": 8.0, "y": 8.0, "flux": 100.0}],
                    "light_curves": {"s": {"kind": "step", "t_on": t_on,
                                           "after": 0.5}}},
        "output": {"path": str(tmp_path / "e.fits"), "truth": True, "fit": ""}})


def test_each_integration_has_its_light_curve_mean_and_rate_their_mean(tmp_path):
    # RAPID x 4, 3 integrations: integration i resets at T_i = 5 i t_frame and its
    # slope spans its reads' times, [T_i + t_frame, T_i + 4 t_frame].  The step
    # (1 -> 0.5) halfway through integration 1's span: means 1, 0.75, 0.5; RATE is
    # their mean, 0.75 (the exposure's span, 15 frames, gave (7.5 + 0.5 x 7.5) / 15).
    engine, _ = build_engine(_scene(tmp_path, 1.0))
    tf = engine.detector.frame_time
    t_on = 5 * tf + 2.5 * tf
    scene = _scene(tmp_path, t_on)
    run_scene(scene, progress=False, options=EngineOptions(threads=1))
    with fits.open(tmp_path / "e_truth.fits") as t:
        lc = t["LCINTS"].data
        src = t["SOURCES"].data
        rate = t["RATE"].data.astype(float)
        nextend = t[0].header["NEXTEND"]
        n_hdu = len(t) - 1
    assert nextend == n_hdu
    row = int(np.flatnonzero(src["light_curve"] == "s")[0])
    assert np.all(lc["SOURCE"] == row)
    np.testing.assert_array_equal(lc["INTEGRATION"], [0, 1, 2])
    np.testing.assert_allclose(lc["T_START"], np.arange(3) * 5 * tf + tf, rtol=1e-12)
    np.testing.assert_allclose(lc["T_END"], np.arange(3) * 5 * tf + 4 * tf, rtol=1e-12)
    np.testing.assert_allclose(lc["LC_MEAN"], [1.0, 0.75, 0.5], rtol=1e-12)
    on = float(src["flux_on_array"][row])
    np.testing.assert_allclose(lc["FLUX"], on * np.array([1.0, 0.75, 0.5]), rtol=1e-12)
    # RATE: the constant star's collected flux plus 0.75 of the variable one's
    const = float(src["flux_on_array"][1 - row])
    assert rate.sum() == pytest.approx(const + 0.75 * on, rel=1e-6)


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
