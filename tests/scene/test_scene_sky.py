"""A scene's [sources] through the run: catalogue light curves, light-curve files, rates.

These go through the code the run uses (``parse_scene`` -> ``scenesim.sky.rates`` ->
the engine -> the exposure file), not through the library functions alone.
"""

import numpy as np
import pytest
from astropy import units as u
from astropy.table import Table

from noise.clock import preset
from scenesim import run_scene
from scenesim.engine import EngineOptions
from scenesim.io.exposure import read_exposure
from scenesim.scene import parse_scene
from scenesim.sky.lightcurve import LightCurve
from scenesim.sky.psf import GaussianPSF, render_point_sources
from scenesim.sky.rates import cosmic_ray_hits, scene_rates

DETECTOR = {"preset": "H2RG", "naxis1": 64, "naxis2": 64}


def step_integral(a, b, t_on, before, after):
    """Closed-form integral over [a, b] of a step from ``before`` to ``after`` at t_on."""
    return (before * (np.minimum(b, t_on) - np.minimum(a, t_on))
            + after * (np.maximum(b, t_on) - np.maximum(a, t_on)))


def test_catalogue_light_curve_column_drives_a_variable_star_end_to_end(tmp_path):
    # Two stars of equal flux from an ECSV catalogue; the first names the scene's
    # light curve "dim" (a step down to 1/4 in mid-exposure), the second none.
    det = preset("H2RG", naxis1=64, naxis2=64)
    tf = det.frame_time
    ngroups, t_on, after, flux = 20, 10.5 * det.frame_time, 0.25, 2e5
    xs, ys = [20.3, 44.2], [20.6, 40.7]
    Table({"x": xs, "y": ys, "flux": [flux, flux], "light_curve": ["dim", ""]}).write(
        tmp_path / "cat.ecsv", format="ascii.ecsv")
    scene = parse_scene({
        "seed": 5,
        "detector": DETECTOR,
        "noise": {"preset": "none"},
        "readout": {"pattern": "RAPID", "ngroups": ngroups},
        "sources": {"catalogue": "cat.ecsv",
                    "psf": {"kind": "gaussian", "fwhm": 2.0},
                    "light_curves": {"dim": {"kind": "step", "t_on": t_on,
                                             "after": after}}},
        "output": {"path": str(tmp_path / "run.fits"), "truth": False},
    }, base_dir=tmp_path)
    # Expected charge, no shot noise: each star's pixel-integrated PSF times its flux
    # integrated over each read interval.  Read k of a pixel with clock offset t_pix is
    # at (1 + k) t_frame + t_pix (rolling reset, docs/CONVENTIONS.md).
    res = run_scene(scene, options=EngineOptions(shot_noise=False), progress=False)
    sci = read_exposure(res.exposure)[0][0].astype(np.float64)     # (ngroups, ny, nx)
    psf = GaussianPSF(2.0)
    w_var, _ = render_point_sources(det.shape, xs[0], ys[0], 1.0, psf)
    w_const, _ = render_point_sources(det.shape, xs[1], ys[1], 1.0, psf)
    tpix = det.pixel_time()
    for k in range(ngroups - 1):
        t1 = (1 + k) * tf + tpix
        t2 = (2 + k) * tf + tpix
        expected = flux * (w_const * tf + w_var * step_integral(t1, t2, t_on, 1.0, after))
        # each read is rounded to whole DN (gain 1): a difference errs by <= 1 DN
        assert np.max(np.abs(sci[k + 1] - sci[k] - expected)) <= 1.0 + 1e-5 * flux * tf
    # and in words: the named star drops to 1/4 after t_on, the other does not
    box_var = (slice(14, 28), slice(13, 28))
    box_const = (slice(34, 48), slice(37, 52))
    d = np.diff(sci, axis=0)
    early, late = slice(0, 8), slice(10, ngroups - 1)     # intervals before / after t_on
    ratio_var = d[late][:, box_var[0], box_var[1]].sum(axis=(1, 2)).mean() / \
        d[early][:, box_var[0], box_var[1]].sum(axis=(1, 2)).mean()
    ratio_const = d[late][:, box_const[0], box_const[1]].sum(axis=(1, 2)).mean() / \
        d[early][:, box_const[0], box_const[1]].sum(axis=(1, 2)).mean()
    assert ratio_var == pytest.approx(after, rel=1e-3)
    assert ratio_const == pytest.approx(1.0, rel=1e-3)


@pytest.mark.parametrize("unit, seconds", [(u.h, 3600.0), (u.d, 86400.0),
                                           (u.min, 60.0), (None, 1.0)])
def test_light_curve_file_through_a_scene_equals_from_file(tmp_path, unit, seconds):
    # Before: the scene path read the 'time' column as seconds whatever its unit (a
    # file in hours ran 3600 times too fast); only LightCurve.from_file converted.
    # Now the scene reads the file through LightCurve.from_file.
    time = np.array([0.0, 1e-3, 2e-3, 4e-3])
    flux = np.array([1.0, 0.5, 0.5, 1.0])
    col = time * unit if unit is not None else time
    path = tmp_path / "lc.ecsv"
    Table({"time": col, "flux": flux}).write(path, format="ascii.ecsv")
    scene = parse_scene({
        "seed": 1,
        "detector": DETECTOR,
        "noise": {"preset": "none"},
        "readout": {"pattern": "RAPID", "ngroups": 2},
        "sources": {"stars": [{"x": 30.0, "y": 30.0, "flux": 100.0,
                               "light_curve": "f"}],
                    "light_curves": {"f": {"kind": "file", "file": "lc.ecsv"}}},
    }, base_dir=tmp_path)
    reference = LightCurve.from_file(path)
    np.testing.assert_allclose(reference.time, time * seconds, rtol=1e-15)
    assert scene.sources.light_curve("f").build() == reference
    _, variable, _ = scene_rates(scene)                 # what the engine receives
    assert len(variable) == 1 and variable[0].light_curve == reference


def test_scene_rates_and_cosmic_rays_use_their_own_streams(tmp_path):
    # Hot pixels and cosmic rays draw from their own streams under the scene seed:
    # switching cosmic rays on does not change the hot pixels, and the same seed
    # gives the same draws.
    base = {
        "seed": 11,
        "detector": DETECTOR,
        "noise": {"preset": "none"},
        "readout": {"pattern": "RAPID", "ngroups": 2},
        "sources": {"dark_current": 0.5, "hot_pixel_fraction": 0.05},
    }
    scene = parse_scene(base)
    with_crs = parse_scene({**base, "effects": {"cosmic_ray_rate": 5e4}})
    rate, variable, rendered = scene_rates(scene)
    assert variable == [] and rendered is None
    ref = scene.detector.reference_mask()
    assert np.all(rate[ref] == 0) and np.all(rate[~ref] >= 0.5)
    assert (rate[~ref] > 0.5).any()                     # some hot pixels
    np.testing.assert_array_equal(scene_rates(with_crs)[0], rate)
    assert cosmic_ray_hits(scene, 10.0) is None
    hits = cosmic_ray_hits(with_crs, 10.0)
    again = cosmic_ray_hits(with_crs, 10.0)
    assert hits.time.size > 0
    for name in ("time", "index", "charge"):
        np.testing.assert_array_equal(getattr(hits, name), getattr(again, name))
    assert not ref.ravel()[hits.index].any()            # no charge on reference pixels


def test_stars_that_miss_the_array_are_named_in_a_warning_and_kept_in_the_truth():
    # A star whose PSF puts nothing on the collecting pixels (far off the array)
    # runs, but the run says so, naming it;
    # the truth catalogue keeps it with flux_on_array = 0.  Stars on the array do not
    # warn.
    from scenesim.sky.rates import SceneWarning
    base = {
        "seed": 3, "detector": DETECTOR, "noise": {"preset": "none"},
        "readout": {"pattern": "RAPID", "ngroups": 2},
        "sources": {"psf": {"kind": "gaussian", "fwhm": 1.0},
                    "stars": [{"x": 30.0, "y": 30.0, "flux": 100.0}]},
    }
    scene_rates(parse_scene(base))                      # no warning (errors here)
    far = [{"x": 1e6, "y": 30.0, "flux": 100.0}, {"x": 30.0, "y": -9.0, "flux": 5.0},
           {"x": -40.0, "y": -40.0, "flux": 1.0}, {"x": 30.0, "y": 1e9, "flux": 1.0}]
    scene = parse_scene({**base, "sources": {**base["sources"],
                                             "stars": base["sources"]["stars"] + far}})
    with pytest.warns(SceneWarning) as caught:
        rate, _, rendered = scene_rates(scene)
    text = str(caught[0].message)
    assert text.startswith("4 of 5 stars put no charge") and "(1e+06, 30)" in text
    assert "(30, -9)" in text and "1 more" in text
    assert list(rendered["flux_on_array"][1:]) == [0.0] * 4
    assert rendered["flux_on_array"][0] > 0 and rate.sum() == pytest.approx(
        rendered["flux_on_array"][0], rel=1e-12)
