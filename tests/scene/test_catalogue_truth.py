"""A catalogue through the run to the truth, and the errors that name its rows.

The case of a tester's report (2026-11-28): a catalogue ``cat.ecsv`` with columns
``id x y flux light_curve`` (and an extra ``mag``), rows 7 (transit ``tr``), 8
(constant) and 9 (step ``fl``), on a 64 x 64 window read RAPID x 20, 3
integrations.  Before, the truth's ``SOURCES`` dropped ``id`` and every other
catalogue column and listed the constant stars first (8, 7, 9), with ``LCINTS.SOURCE``
indexing that order; a too-bright row, a huge map or a ``file`` light curve with a
huge peak failed with "'rate' (with the variable sources at their peak) ...", naming
no file, row or pixel; a light-curve file's ``flux`` in ``mag`` was used as a factor.
"""

import numpy as np
import pytest
from astropy import units as u
from astropy.io import fits
from astropy.table import Table

from noise.errors import FileFormatError, ParameterError
from scenesim import run_scene
from scenesim.engine import EngineOptions
from scenesim.scene import parse_scene

IDS = [7, 8, 9]
XS = [20.3, 44.1, 20.5]
YS = [20.2, 44.7, 44.5]
CURVES = ["tr", "", "fl"]


def _catalogue(tmp_path, flux=(2e4, 2e4, 2e4), name="cat.ecsv", **extra):
    table = Table({"id": IDS, "x": XS, "y": YS, "flux": list(flux),
                   "light_curve": CURVES})
    table["mag"] = [10.1, 10.2, 10.3]
    for key, value in extra.items():
        table[key] = value
    table.write(tmp_path / name, overwrite=True)
    return str(tmp_path / name)


def _scene(tmp_path, *, stars=(), curves=None, sources=None, effects=None,
           catalogue="cat.ecsv"):
    src = {"psf": {"kind": "gaussian", "fwhm": 2.0},
           "light_curves": curves or {
               "tr": {"kind": "transit", "t0": 0.58, "duration": 0.3, "depth": 0.01},
               "fl": {"kind": "step", "t_on": 0.6, "after": 2.0}}}
    if catalogue is not None:
        src["catalogue"] = catalogue
    if stars:
        src["stars"] = list(stars)
    src.update(sources or {})
    return parse_scene({
        "seed": 11, "detector": {"preset": "H2RG", "naxis1": 64, "naxis2": 64},
        "noise": {"preset": "none"},
        "readout": {"pattern": "RAPID", "ngroups": 20, "nints": 3},
        "sources": src, "effects": effects or {},
        "output": {"path": str(tmp_path / "t.fits"), "truth": True}},
        base_dir=tmp_path)


# ---------------------------------------------------------- light-curve flux units
def test_a_light_curve_file_in_magnitudes_is_refused_when_the_scene_loads(tmp_path):
    _catalogue(tmp_path)
    Table({"time": [0.0, 0.5, 1.0], "flux": [0.0, 0.01, 0.0] * u.mag}).write(
        tmp_path / "dip.ecsv")
    with pytest.raises(FileFormatError) as info:
        _scene(tmp_path, curves={"tr": {"kind": "file", "file": "dip.ecsv"},
                                 "fl": {"kind": "step", "t_on": 0.6, "after": 2.0}})
    msg = str(info.value)
    assert msg.startswith("[sources.light_curves.tr] light-curve file ")
    assert str(tmp_path / "dip.ecsv") in msg and "'flux'" in msg and "'mag'" in msg


# ------------------------------------------------------------ SOURCES and LCINTS
def _truth(tmp_path, scene):
    run_scene(scene, progress=False, options=EngineOptions(threads=1, shot_noise=False),
              overwrite=True)
    with fits.open(tmp_path / "t_truth.fits") as hdul:
        return Table.read(hdul["SOURCES"]), Table.read(hdul["LCINTS"])


@pytest.mark.parametrize("inline", [0, 1])
def test_sources_keep_the_catalogue_order_id_and_columns(tmp_path, inline):
    # rows 7, 8, 9 in the catalogue's order (before: 8, 7, 9 and no id or mag), after
    # the inline star when there is one; LCINTS.SOURCE is the row of each variable one
    _catalogue(tmp_path)
    stars = [{"x": 30.0, "y": 30.0, "flux": 5000.0}][:inline]
    src, lc = _truth(tmp_path, _scene(tmp_path, stars=stars))
    assert src.colnames[:4] == ["id", "x", "y", "flux"] and src.colnames[-1] == "mag"
    assert len(src) == inline + 3
    cat = src[inline:]
    assert list(cat["id"]) == IDS and list(cat["x"]) == XS and list(cat["y"]) == YS
    np.testing.assert_allclose(cat["mag"], [10.1, 10.2, 10.3])
    assert [str(v) for v in np.ma.filled(cat["light_curve"], "")] == CURVES
    if inline:                  # the inline star: its own x, y; null id and mag
        assert src["x"][0] == 30.0 and src["id"].mask[0] and src["mag"].mask[0]
        assert not np.any(cat["id"].mask)
    assert list(lc["SOURCE"]) == [inline] * 3 + [inline + 2] * 3
    for row in lc:
        assert (row["X"], row["Y"]) == (src["x"][row["SOURCE"]], src["y"][row["SOURCE"]])
    # the transit (row 7) dips in integration 1 only; the step (row 9) doubles from 2
    tr, fl = lc[:3], lc[3:]
    assert tr["LC_MEAN"][0] == pytest.approx(1.0) and tr["LC_MEAN"][1] < 1.0
    assert fl["LC_MEAN"][0] == pytest.approx(1.0) and fl["LC_MEAN"][2] == \
        pytest.approx(2.0)


def test_catalogue_columns_named_as_rendering_columns_are_kept_renamed(tmp_path):
    # string ids; a column 'flux_on_array' (a truth's SOURCES used as a catalogue)
    # is kept as 'catalogue_flux_on_array' beside the rendering's own
    Table({"id": ["a", "b", "c"], "x": XS, "y": YS, "flux": [2e4] * 3,
           "light_curve": CURVES, "Flux_On_Array": [1.0, 2.0, 3.0]}).write(
        tmp_path / "cat.ecsv")
    src, _ = _truth(tmp_path, _scene(tmp_path))
    assert list(src["id"]) == ["a", "b", "c"]
    assert list(src["catalogue_Flux_On_Array"]) == [1.0, 2.0, 3.0]
    assert src["flux_on_array"][1] == pytest.approx(2e4, rel=1e-6)


def test_a_catalogue_column_fits_cannot_hold_is_refused_when_the_scene_loads(tmp_path):
    table = Table({"id": IDS, "x": XS, "y": YS, "flux": [2e4] * 3,
                   "light_curve": CURVES})
    table["tags"] = np.array([{"a": 1}, [1, 2], "x"], dtype=object)
    table.write(tmp_path / "cat.ecsv")
    with pytest.raises(FileFormatError) as info:
        _scene(tmp_path)
    msg = str(info.value)
    assert msg.startswith("[sources] catalogue ") and str(tmp_path / "cat.ecsv") in msg
    assert "'tags'" in msg and "object" in msg and "\n" not in msg


# ------------------------------------------------- too much charge: name its source
def _refused(tmp_path, scene):
    with pytest.raises(ParameterError) as info:
        run_scene(scene, progress=False, options=EngineOptions(threads=1))
    assert not list(tmp_path.glob("t*.fits"))          # refused before any work
    msg = str(info.value)
    assert "\n" not in msg and "'rate'" not in msg and "2**53" in msg
    return msg


def test_a_too_bright_catalogue_row_is_named_with_its_file_row_and_id(tmp_path):
    path = _catalogue(tmp_path, flux=(2e4, 1e22, 2e4))
    msg = _refused(tmp_path, _scene(tmp_path, stars=[{"x": 5.0, "y": 5.0,
                                                      "flux": 10.0}]))
    assert msg.startswith(f"[sources] catalogue {path!r} row 1 (id 8) 'flux' = 1e+22 "
                          f"e-/s puts ")
    assert "pixel (x, y) = (44, 45)" in msg
    assert "light_curves" not in msg and "variable" not in msg   # row 8 is constant


def test_a_huge_map_pixel_is_named_with_its_file_and_pixel(tmp_path):
    # the scene has variable stars, but none in that pixel: no light curve named
    _catalogue(tmp_path)
    dark = np.full((64, 64), 0.5)
    dark[10, 12] = 2e19
    fits.writeto(tmp_path / "dark.fits", dark)
    msg = _refused(tmp_path, _scene(tmp_path, sources={"dark_current": "dark.fits"}))
    assert msg.startswith(f"[sources] 'dark_current' map "
                          f"{str(tmp_path / 'dark.fits')!r} puts 2e+19 e-/s on pixel "
                          f"(x, y) = (12, 10) of the read-out image, which would collect")
    assert "light_curves" not in msg and "variable" not in msg


def test_a_huge_flat_under_a_variable_star_names_the_row_its_curve_and_the_flat(
        tmp_path):
    path = _catalogue(tmp_path)
    flat = np.ones((64, 64))
    flat[20, 20] = 1e19
    fits.writeto(tmp_path / "flat.fits", flat)
    msg = _refused(tmp_path, _scene(tmp_path, sources={"background": 3.0},
                                    effects={"flat": "flat.fits"}))
    flat_name = f"[effects] 'flat' map {str(tmp_path / 'flat.fits')!r} (1e+19 at that " \
        f"pixel)"
    assert msg.startswith(f"[sources] catalogue {path!r} row 0 (id 7) 'flux' = 20000 "
                          f"e-/s x [sources.light_curves.tr] peak 1 x {flat_name} puts ")
    assert "pixel (x, y) = (20, 20)" in msg
    assert f"from [sources] 'background' = 3.0 e-/s x {flat_name}" in msg


def test_a_file_light_curve_with_a_huge_peak_is_named(tmp_path):
    # LightCurveConfig.peak() is None for a file curve: the scene could not check it
    path = _catalogue(tmp_path)
    Table({"time": [0.0, 0.2, 0.4], "flux": [1.0, 1e18, 1.0]}).write(tmp_path / "lc.ecsv")
    msg = _refused(tmp_path, _scene(tmp_path, curves={
        "tr": {"kind": "file", "file": "lc.ecsv"},
        "fl": {"kind": "step", "t_on": 0.6, "after": 2.0}}))
    assert msg.startswith(
        f"[sources] catalogue {path!r} row 0 (id 7) 'flux' = 20000 e-/s x "
        f"[sources.light_curves.tr] peak 1e+18 (file {str(tmp_path / 'lc.ecsv')!r}) "
        f"puts ")


def test_the_engine_names_the_pixel_and_variable_sources_only_when_there_are_some():
    from noise.clock import preset
    from scenesim.detector.readout import Readout
    from scenesim.engine import ChargeEngine, VariableSource
    from scenesim.sky.lightcurve import LightCurve
    det = preset("H2RG", naxis1=64, naxis2=64)
    rate = np.zeros(det.shape)
    rate[30, 40] = 1e20
    ro = Readout.named("RAPID", 20, nints=3)
    with pytest.raises(ParameterError) as info:
        ChargeEngine(det, ro, rate=rate, rng=11)
    msg = str(info.value)
    assert msg.startswith("'rate' is 1e+20 e-/s at pixel (x, y) = (40, 30), which")
    assert "variable" not in msg
    var = VariableSource(np.array([30 * 64 + 40]), np.array([1.0]),
                         LightCurve([0.0, 1.0], [1.0, 1e20]))
    with pytest.raises(ParameterError, match=r"^'rate' is 1e\+20 e-/s and "
                       r"'variable_sources' add 1e\+20 e-/s at their light curves' "
                       r"peak at pixel \(x, y\) = \(40, 30\)"):
        ChargeEngine(det, ro, rate=rate, variable_sources=[var], rng=11)
