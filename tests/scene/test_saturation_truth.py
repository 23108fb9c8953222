"""The truth's saturation: the ADC's top code clips as surely as the full well.

Found by a probe (2026-11-27): a 2e6 e-/s star on a 64 x 64 array with a full well of
1e5 e- at 1 e-/DN (above the 16-bit top code, 65535 e-) read 65535 DN on its last read
while the truth said ``SATREAD = -1`` (never), so ``compare`` judged the clipped read
usable; and a readout of more than 32767 reads overflowed the int16 ``SATREAD`` with
a traceback.  Noise is off: every expected value follows from the charge alone.
"""

import numpy as np
from astropy.io import fits

from scenesim.engine import EngineOptions
from scenesim.run import run_scene
from scenesim.scene import parse_scene


def _scene(tmp_path, readout, sources, effects):
    return parse_scene({
        "seed": 5, "detector": {"preset": "H2RG", "naxis1": 64, "naxis2": 64},
        "noise": {"preset": "none"}, "readout": readout, "sources": sources,
        "effects": effects,
        "output": {"path": str(tmp_path / "e.fits"), "truth": True, "fit": ""}})


def _run(scene):
    run_scene(scene, progress=False, options=EngineOptions(threads=1))


def test_reads_at_the_adc_top_code_are_saturated_in_the_truth(tmp_path):
    # Full well 1e5 e- above the ADC's 65535 e-: the star's peak clips at the ADC.
    scene = _scene(tmp_path, {"pattern": "RAPID", "ngroups": 10},
                   {"background": 1.0, "psf": {"kind": "gaussian", "fwhm": 2.0},
                    "stars": [{"x": 30.0, "y": 30.0, "flux": 2e6}]},
                   {"full_well": 1e5, "gain": 1.0})
    _run(scene)
    with fits.open(tmp_path / "e.fits") as e, fits.open(tmp_path / "e_truth.fits") as t:
        sci = e["SCI"].data[0].astype(np.int64)             # (ngroups, ny, nx)
        satread = t["SATREAD"].data[0]
        satgroup = t["SATGROUP"].data[0]
    top = sci == 65535
    assert top.any()                                      # the case is the probe's
    # RAPID: read k is resultant k.  Every pixel with a read at the top code is
    # saturated from its first such read (the charge only grows, so no later read
    # is below it), and no pixel without one is saturated (no full well reached:
    # 1e5 e- is beyond the top code).
    first = np.where(top.any(axis=0), top.argmax(axis=0), -1)
    np.testing.assert_array_equal(satread, first)
    np.testing.assert_array_equal(satgroup, first)


def test_a_readout_beyond_32767_reads_keeps_its_saturated_read(tmp_path):
    # 1000 e-/s for 40001 frames of 18.2 ms (728 s): 7.3e5 e-, past the 1e5 e- well
    # between the two reads taken, so read 40000 is the first saturated one (an
    # int16 SATREAD overflowed there).
    scene = _scene(tmp_path, {"resultants": [[0], [40000]]}, {"dark_current": 1000.0},
                   {"full_well": 1e5, "gain": 2.0})
    _run(scene)
    with fits.open(tmp_path / "e_truth.fits") as t:
        satread, satgroup = t["SATREAD"].data, t["SATGROUP"].data
    assert satread.dtype.itemsize == 4
    regular = slice(4, -4)
    assert np.all(satread[0, regular, regular] == 40000)
    assert np.all(satgroup[0, regular, regular] == 1)
