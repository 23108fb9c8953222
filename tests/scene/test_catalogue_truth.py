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

import pytest
from astropy import units as u
from astropy.table import Table

from noise.errors import FileFormatError
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
               "tr": {"kind": "transit", "t0": 0.5, "duration": 0.4, "depth": 0.01},
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
