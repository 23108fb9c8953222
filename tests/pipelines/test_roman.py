"""Roman: L1 ASDF files that roman_datamodels opens, their read pattern against
romancal's resultant times, and romancal's ramp fit graded by ``compare`` (needs the
``roman`` extra; skipped without it)."""

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("roman_datamodels")
pytest.importorskip("romancal")

import roman_datamodels as rdm  # noqa: E402

from scenesim.io.exposure import read_exposure  # noqa: E402
from scenesim.io.header import readout_from_table  # noqa: E402
from scenesim.validate.compare import compare_files  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
DATA = os.path.join(HERE, "..", "data", "pipelines")

pytestmark = [pytest.mark.filterwarnings("ignore::DeprecationWarning"),
              pytest.mark.filterwarnings("ignore::PendingDeprecationWarning"),
              pytest.mark.filterwarnings("ignore::RuntimeWarning"),
              pytest.mark.filterwarnings("ignore::UserWarning")]


def _scenesim(*args, cwd):
    res = subprocess.run([sys.executable, "-m", "scenesim.cli", *args], cwd=cwd,
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    return res.stdout


@pytest.fixture(scope="module")
def roman_loop(tmp_path_factory):
    """The CI loop: run (L1 + references), then romancal's ramp fit, then compare."""
    d = tmp_path_factory.mktemp("roman_loop")
    shutil.copy(os.path.join(DATA, "roman_loop.toml"), d)
    _scenesim("run", "roman_loop.toml", "--l1", "--reffiles", "-q", cwd=d)
    text = _scenesim("pipeline", "roman", "roman_loop_l1.asdf", "--refs",
                     "roman_loop_refs", "--truth", "roman_loop_truth.fits",
                     "--exposure", "roman_loop.fits", cwd=d)
    return d, text


def test_l1_opens_and_its_read_times_are_ours(roman_loop):
    d, _ = roman_loop
    sci, hdr, reads = read_exposure(str(d / "roman_loop.fits"))
    ro = readout_from_table(hdr, reads)
    with rdm.open(str(d / "roman_loop_l1.asdf")) as m:
        assert type(m).__name__ == "ScienceRawModel"
        m.validate()
        assert np.array_equal(m.data, sci[0])
        assert m.amp33.shape == (ro.ngroups, sci.shape[2], 128)
        pattern = [list(r) for r in m.meta.exposure.read_pattern]
        t = float(m.meta.exposure.frame_time)
    assert t == hdr["TFRAME"]
    # romancal's resultant time: mean of the 1-based read indices times frame_time
    # (romancal.ramp_fitting, stcal cas22); ours: Readout.mean_times, rolling reset
    theirs = np.array([np.mean(r) * t for r in pattern])
    assert np.allclose(theirs, ro.mean_times(t), rtol=0, atol=1e-12)


def test_romancal_fit_is_graded(roman_loop):
    d, text = roman_loop
    assert "fit layout: roman" in text
    report = compare_files(str(d / "roman_loop_l2.asdf"),
                           str(d / "roman_loop_truth.fits"),
                           exposure=str(d / "roman_loop.fits"))
    rows = [r for r in report.rows if r["n"] >= 10]
    assert rows
    # the bright bins (shot noise dominates the read noise that romancal cannot
    # reference-correct without refpix): unbiased within 1 sigma, errors right
    for row in rows:
        if row["lo"] >= 10:
            assert abs(row["bias_rep"]) < 1.0, row
            assert 0.5 < row["chi2_rep"] < 2.0, row
    assert report.photometry["median_ratio"] == pytest.approx(1.0, abs=0.03)


def test_roman_scene_l1(tmp_path):
    """The Roman example scene's readout as an L1 file, on a window (the full 4096^2
    scene is the slow test below)."""
    from scenesim.scene import load_scene
    from scenesim.run import run_scene
    from scenesim.pipelines.roman import write_l1
    scene = load_scene(os.path.join(ROOT, "scenes", "roman_h4rg.toml"))
    det = scene.detector.window(0, 0, 32, 32)
    res = run_scene(scene.replace(detector=det), output=str(tmp_path / "r.fits"),
                    progress=False)
    write_l1(res.exposure, str(tmp_path / "r_l1.asdf"))
    with rdm.open(str(tmp_path / "r_l1.asdf")) as m:
        m.validate()
        assert len(m.meta.exposure.read_pattern) == 9


def test_saturation_step_flags_the_adc_top_and_the_fit_keeps_the_rest(roman_loop,
                                                                       tmp_path):
    """roman_loop sets no full well, so its saturation reference is the ADC's top
    code: a pixel whose last two resultants are put at 65535 DN is flagged SATURATED
    by romancal's saturation step, and its slope, fitted on the four resultants
    left, still matches the truth within 5 of the errors romancal reports."""
    from scenesim.pipelines.command import reference_paths
    from scenesim.pipelines.roman import run_ramp_fit
    from scenesim.io.exposure import read_truth
    d, _ = roman_loop
    refs = reference_paths(d / "roman_loop_refs", "roman")
    assert "saturation" in refs
    with rdm.open(refs["saturation"]) as s:
        assert np.all(s.data == 65535)
    y, x = 71, 60                                   # the bright star's peak (2e4 e-/s)
    with rdm.open(str(d / "roman_loop_l1.asdf")) as m:
        m.data[-2:, y, x] = 65535
        m.to_asdf(str(tmp_path / "sat_l1.asdf"))
    run_ramp_fit(str(tmp_path / "sat_l1.asdf"), refs, str(tmp_path / "sat_l2.asdf"))
    b = 4                                           # the border romancal trims
    with rdm.open(str(tmp_path / "sat_l2.asdf")) as m:
        assert m.meta.cal_step.saturation == "COMPLETE"
        assert int(m.dq[y - b, x - b]) & 2          # SATURATED
        slope = float(m.data[y - b, x - b]) * 2.0   # e-/s (gain 2)
        sigma = float(np.sqrt(m.var_poisson[y - b, x - b]
                              + m.var_rnoise[y - b, x - b])) * 2.0
    truth = read_truth(str(d / "roman_loop_truth.fits"))["RATE"][y, x]
    assert truth > 1000
    assert abs(slope - truth) < 5 * sigma
