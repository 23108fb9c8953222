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
        # the end is the start plus the exposure time (before: the same instant)
        ex = m.meta.exposure
        assert (ex.end_time - ex.start_time).sec == pytest.approx(ex.exposure_time,
                                                                  abs=1e-3)
        assert ex.exposure_time > 0
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


# ------------------------------------------------------- linearity and dark references
NONLINEAR = "roman_nonlinear"


def test_linearity_and_dark_references_undo_the_engine(tmp_path):
    """The Roman linearity pair, evaluated as stcal evaluates it (float32 Horner on
    raw DN, bias included), returns the linear charge of the engine's law, and the
    inverse returns the raw DN; the dark slope is the dark reference in DN/s.  No
    romancal step runs here."""
    stcal_linearity = pytest.importorskip("stcal.linearity.linearity")
    from scenesim.pipelines.reffiles import detector_reference
    from scenesim.pipelines.roman import write_reference_files
    from scenesim.run import build_engine
    from scenesim.scene import load_scene
    scene = load_scene(os.path.join(DATA, NONLINEAR + ".toml"))
    engine, _ = build_engine(scene)
    ref = detector_reference(scene, engine)
    paths = write_reference_files(ref, tmp_path / "refs")
    assert set(paths) == {"gain", "readnoise", "mask", "saturation", "linearity",
                          "inverselinearity", "dark"}
    g = ref.gain
    with rdm.open(paths["linearity"]) as m:
        m.validate()
        lin = np.asarray(m.coeffs)
    with rdm.open(paths["inverselinearity"]) as m:
        m.validate()
        inv = np.asarray(m.coeffs)
    with rdm.open(paths["dark"]) as m:
        m.validate()
        assert np.allclose(np.asarray(m.dark_slope, np.float64) * g, ref.dark,
                           rtol=1e-6, atol=0)                     # float32 storage
    assert lin.dtype == inv.dtype == np.float32
    # raw DN of charge q (e-) on every pixel: bias + p(q), the engine without noise
    q = np.linspace(0, 8e4, 41)
    raw = (ref.bias[None] + engine.nonlinearity.apply(q)[:, None, None]) / g
    shape = (lin.shape[0],) + raw.shape
    got = stcal_linearity.apply_polynomial(raw.astype(np.float32),
                                           np.broadcast_to(lin[:, None], shape))
    # tolerance: the polynomial's own error (linearity_error, e-) plus float32
    # round-off, ~ 8 operations x 2**-24 x the largest raw value (6e4 DN): 0.03 DN
    tol = ref.linearity_error / g + 8 * 2.0 ** -24 * float(raw.max())
    assert np.max(np.abs(got - q[:, None, None] / g)) < tol
    back = stcal_linearity.apply_polynomial(
        got, np.broadcast_to(inv[:, None], (inv.shape[0],) + raw.shape))
    assert np.max(np.abs(back - raw)) < 2 * tol
    # the null limit: a linear detector writes neither linearity file, and removes
    # those of an earlier run from the directory it overwrites
    import dataclasses
    linear = scene.replace(effects=dataclasses.replace(scene.effects, nonlinearity=()))
    engine0, _ = build_engine(linear)
    paths0 = write_reference_files(detector_reference(linear, engine0),
                                   tmp_path / "refs", overwrite=True)
    assert "linearity" not in paths0 and "inverselinearity" not in paths0
    assert not os.path.exists(paths["linearity"])
    assert not os.path.exists(paths["inverselinearity"])


@pytest.fixture(scope="module")
def roman_nonlinear(tmp_path_factory):
    """run (L1 + references), then romancal with linearity and dark, and once more
    without the linearity files (in this process: the CLI loop is roman_loop's)."""
    from scenesim.pipelines.command import reference_paths, write_run_products
    from scenesim.pipelines.roman import run_ramp_fit
    from scenesim.run import run_scene
    from scenesim.scene import load_scene
    d = tmp_path_factory.mktemp(NONLINEAR)
    scene = load_scene(os.path.join(DATA, NONLINEAR + ".toml"))
    result = run_scene(scene, output=str(d / f"{NONLINEAR}.fits"), progress=False)
    write_run_products(scene, result, l1=True, reffiles=True)
    refs = reference_paths(d / f"{NONLINEAR}_refs", "roman")
    run_ramp_fit(str(d / f"{NONLINEAR}_l1.asdf"), refs, str(d / f"{NONLINEAR}_l2.asdf"))
    nolin = {t: p for t, p in refs.items() if "linearity" not in t}
    run_ramp_fit(str(d / f"{NONLINEAR}_l1.asdf"), nolin, str(d / "nolin_l2.asdf"))
    return d


def _pulls(l2, d):
    """(fit - truth) / sigma_reported per pixel, e-/s, the dark the L2 names taken
    out of the truth; and the mask of pixels the fit did not flag."""
    from scenesim.io.exposure import read_truth
    from scenesim.pipelines.products import (fit_header, read_roman_l2,
                                             subtracted_dark_rate)
    truth = read_truth(str(d / f"{NONLINEAR}_truth.fits"))
    g = float(truth["header"]["GAIN"])
    fit = read_roman_l2(l2, gain=g)
    dark, _ = subtracted_dark_rate(fit_header(l2), float(truth["header"]["TFRAME"]), g)
    rate = truth["RATE"] - (0.0 if dark is None else dark)
    z = (fit["slope"] - rate) / np.sqrt(fit["var"])
    return z, fit["dq"], dark


def test_romancal_linearity_and_dark_give_unbiased_slopes(roman_nonlinear):
    """With scenesim's linearity pair and dark, romancal's slopes of a background that
    ends 4.5 % nonlinear (2e4 e-/s, ~5e4 e-) are unbiased: the mean pull of the
    unflagged pixels is within 5 / sqrt(N) of 0; the hot pixels (500-5000 e-/s of
    dark, flagged HOT, still fitted) agree with the truth minus the dark they were
    given, each within 5 sigma.  Without the linearity files the same fit is many
    sigma low (the test can fail)."""
    d = roman_nonlinear
    with rdm.open(str(d / f"{NONLINEAR}_l2.asdf")) as m:
        assert m.meta.cal_step.linearity == "COMPLETE"
        assert m.meta.cal_step.dark == "COMPLETE"
    z, dq, dark = _pulls(str(d / f"{NONLINEAR}_l2.asdf"), d)
    assert dark is not None
    good = dq == 0
    n = int(good.sum())
    assert n > 2500
    # pulls of unit variance (shot noise dominates: ~90 e-/s per pixel, so the
    # pedestal and 1/f noise common to the window, ~1 e-/s of slope, add < 0.02 to
    # the mean): 5 sigma of the mean of N pulls
    assert abs(z[good].mean()) < 5 / np.sqrt(n), z[good].mean()
    assert 0.8 < z[good].std() < 1.2
    hot = (dq & 2048) != 0
    hot &= (dq & ~np.uint32(2048 | 4)) == 0         # HOT (and JUMP_DET) only
    assert hot.sum() > 20
    assert np.all(np.abs(z[hot]) < 5), z[hot]
    # the same exposure without linearity: the later resultants are up to 4.5 % low,
    # the ramps bend (romancal flags most of them JUMP_DET, still fitted) and the
    # slopes fall far below the truth (measured: mean pull -4.7, 50 times the bound
    # above)
    z0, dq0, _ = _pulls(str(d / "nolin_l2.asdf"), d)
    fitted = (dq0 & ~np.uint32(4)) == 0
    assert z0[fitted].mean() < -10 * 5 / np.sqrt(n)


def test_romancal_slopes_are_unbiased_and_its_pulls_follow_its_error_model(tmp_path):
    """roman_loop's window with white read noise only (no pedestal, 1/f, ACN or
    picture frame: nothing common to the window, which romancal cannot remove
    without refpix): romancal's slopes of the 2 e-/s background are unbiased
    against the optimal sigma, so our L1's read times, gain, read-noise convention
    and saturation level agree with romancal's.  Its reported pulls are not: its
    Poisson variance is ``k * slope`` of each pixel's own slope (0 for a negative
    one), so the mean pull is ``E[r / sqrt(V_read + k max(rate + r, 0))]`` over the
    slope error ``r ~ N(0, V)``: about -0.12 here (docs/VALIDATION_PIPELINES.md)."""
    import dataclasses
    from scenesim.io.exposure import read_truth
    from scenesim.pipelines.reffiles import detector_reference
    from scenesim.pipelines.roman import run_ramp_fit, write_l1, write_reference_files
    from scenesim.run import run_scene
    from scenesim.scene import load_scene
    scene = load_scene(os.path.join(DATA, "roman_loop.toml"))
    scene = scene.replace(noise=dataclasses.replace(
        scene.noise, c_pink=0.0, u_pink=0.0, acn=0.0, pca0=0.0, pedestal=0.0))
    res = run_scene(scene, output=str(tmp_path / "w.fits"), progress=False)
    write_l1(res.exposure, str(tmp_path / "w_l1.asdf"))
    refs = write_reference_files(detector_reference(scene, res.engine), tmp_path / "r")
    run_ramp_fit(str(tmp_path / "w_l1.asdf"), refs, str(tmp_path / "w_l2.asdf"))
    report = compare_files(str(tmp_path / "w_l2.asdf"), str(tmp_path / "w_truth.fits"),
                           exposure=str(tmp_path / "w.fits"))
    row = next(r for r in report.rows if r["lo"] == 1)
    assert row["n"] > 10000
    # slopes: mean (fit - truth) / sigma_opt within 5 standard errors (measured
    # +0.001 +- 0.005 over 5 seeds)
    assert abs(row["bias_opt"]) < 5 * row["se_bias"], row
    # pulls with romancal's own errors, against its error model
    b = 4                                               # the border romancal trims
    rate = read_truth(str(tmp_path / "w_truth.fits"))["RATE"][b:-b, b:-b]
    g = 2.0
    with rdm.open(str(tmp_path / "w_l2.asdf")) as m:
        slope = np.asarray(m.data, np.float64) * g
        vp = np.asarray(m.var_poisson, np.float64) * g * g
        vr = np.asarray(m.var_rnoise, np.float64) * g * g
        ok = (np.asarray(m.dq) == 0) & (rate > 1) & (rate < 10)
    r = slope - rate
    z = r[ok] / np.sqrt(vp[ok] + vr[ok])
    pos = ok & (slope > 0.5)
    k = np.median(vp[pos] / slope[pos])                 # (e-/s) per (e-/s) of slope
    x, w = np.polynomial.hermite_e.hermegauss(101)      # E over N(0, V)
    w = w / w.sum()
    dr = x * np.sqrt(r[ok].var())
    predicted = np.sum(w * dr / np.sqrt(np.median(vr[ok])
                                        + k * np.maximum(np.median(rate[ok]) + dr, 0)))
    n = z.size
    # 5 standard errors of a mean of n unit-variance pulls; the prediction is about
    # 3 of these from 0, so a romancal that reported its variance at the true rate
    # would fail here
    assert abs(z.mean() - predicted) < 5 / np.sqrt(n), (z.mean(), predicted)
    assert predicted < -2 * 5 / np.sqrt(n)


@pytest.mark.filterwarnings("ignore:The ols_cas22 function is deprecated")
def test_a_short_ma_table_is_fitted_by_ols_cas22_and_likely_refused_first(tmp_path):
    """romancal's 'likely' fit needs 4 resultants (stcal's likelihood fit): a
    3-resultant table ended in stcal's traceback (a probe).  By default the loop
    takes 'ols_cas22' there; 'likely' asked for is refused before any step runs,
    and one resultant (no slope) is refused whatever the algorithm.  The
    ols_cas22 slopes of the 30 e-/s background are unbiased against the optimum
    within 5 of the bin's standard errors."""
    import dataclasses
    from noise.errors import ParameterError
    from scenesim.pipelines.reffiles import detector_reference
    from scenesim.pipelines.roman import run_ramp_fit, write_l1, write_reference_files
    from scenesim.run import run_scene
    from scenesim.scene import load_scene
    scene = load_scene(os.path.join(DATA, "roman_loop.toml"))
    refs = None
    for name, table in (("three", [[0, 1], [1, 2], [3, 3]]), ("one", [[0, 4]])):
        ro = dataclasses.replace(scene.readout, ma_table=table, name="SHORT")
        sc = scene.replace(readout=ro)
        res = run_scene(sc, output=str(tmp_path / f"{name}.fits"), progress=False)
        write_l1(res.exposure, str(tmp_path / f"{name}_l1.asdf"))
        refs = write_reference_files(detector_reference(sc, res.engine),
                                     tmp_path / f"{name}_refs")
        if name == "one":
            with pytest.raises(ParameterError, match="1 resultant: a ramp fit needs"):
                run_ramp_fit(str(tmp_path / "one_l1.asdf"), refs,
                             str(tmp_path / "one_l2.asdf"))
            assert not (tmp_path / "one_l2.asdf").exists()
            continue
        with pytest.raises(ParameterError, match="'likely' needs at least 4 "
                                                 "resultants.*has 3"):
            run_ramp_fit(str(tmp_path / "three_l1.asdf"), refs,
                         str(tmp_path / "three_l2.asdf"), algorithm="likely")
        assert not (tmp_path / "three_l2.asdf").exists()
        run_ramp_fit(str(tmp_path / "three_l1.asdf"), refs, str(tmp_path / "three_l2.asdf"))
        report = compare_files(str(tmp_path / "three_l2.asdf"),
                               str(tmp_path / "three_truth.fits"),
                               exposure=str(tmp_path / "three.fits"))
        row = max(report.rows, key=lambda r: r["n"])
        assert row["n"] > 1000 and abs(row["bias_opt"]) < 5 * row["se_bias"], row


def test_pipeline_roman_never_replaces_an_input_and_checks_first(roman_loop, tmp_path):
    """The L2 may not be the L1, a reference or the truth, even with --overwrite; the
    input must be an L1 (not an L2 or a FITS file); the L2 ends in .asdf."""
    d, _ = roman_loop
    w = tmp_path / "w"
    w.mkdir()
    shutil.copy(d / "roman_loop_l1.asdf", w / "l1.asdf")
    shutil.copy(d / "roman_loop_l2.asdf", w / "l2.asdf")
    shutil.copy(d / "roman_loop_truth.fits", w / "truth.fits")
    shutil.copytree(d / "roman_loop_refs", w / "refs")
    gain = next(p.name for p in (w / "refs").iterdir() if "gain" in p.name)
    # another run's references (same detector and size, another reference id)
    import roman_datamodels.datamodels as rdd
    shutil.copytree(d / "roman_loop_refs", w / "refs_run")
    with rdd.open(w / "refs" / "roman_mask.asdf") as m, \
            rdd.open(w / "l1.asdf") as l1:
        assert m.meta["scenesim_refid"] == l1.meta["scenesim_refid"]
        m.meta["scenesim_refid"] = "0123456789abcdef"
        m.to_asdf(w / "refs_run" / "roman_mask.asdf")
    before = {p: p.read_bytes() for p in w.rglob("*") if p.is_file()}
    for args, words in (
            (["l1.asdf", "-o", "l1.asdf"], ["l1.asdf", "reads"]),
            (["l1.asdf", "-o", f"refs/{gain}"], [gain, "reads"]),
            (["l2.asdf"], ["ImageModel", "not an L1"]),
            (["truth.fits", "-o", "x.asdf"], ["not a Roman ASDF"]),
            (["l1.asdf", "-o", "x.fits"], ["must end in .asdf"]),
            (["l1.asdf", "-o", "x.asdf", "--refs", "refs_run"],
             ["mask reference", "another run's detector", "0123456789abcdef"])):
        if "--refs" not in args:
            args = [*args, "--refs", "refs"]
        res = subprocess.run([sys.executable, "-m", "scenesim.cli", "pipeline", "roman",
                              *args, "--overwrite"], cwd=w,
                             capture_output=True, text=True)
        assert res.returncode == 2, res.stderr
        lines = res.stderr.strip().splitlines()
        assert len(lines) == 1 and all(word in lines[0] for word in words), res.stderr
    assert {p: p.read_bytes() for p in w.rglob("*") if p.is_file()} == before


def test_compare_takes_only_an_l2_and_a_damaged_l1_is_refused_first(roman_loop,
                                                                     tmp_path):
    """compare given an L1 or a reference as slopes raised AttributeError tracebacks;
    a cut L1 (its blocks load lazily) passed the pipeline's input check and failed
    inside romancal (IndexError), and compare on it raised ValueError."""
    from noise.errors import FileFormatError
    d, _ = roman_loop
    truth = str(d / "roman_loop_truth.fits")
    dark = next(p for p in (d / "roman_loop_refs").iterdir() if "dark" in p.name)
    for path, words in ((d / "roman_loop_l1.asdf", "ScienceRawModel, not an L2"),
                        (dark, "DarkRefModel, not an L2")):
        with pytest.raises(FileFormatError, match=words):
            compare_files(str(path), truth)
    data = (d / "roman_loop_l1.asdf").read_bytes()
    cut = tmp_path / "cut_l1.asdf"
    cut.write_bytes(data[:len(data) // 2])
    res = subprocess.run([sys.executable, "-m", "scenesim.cli", "pipeline", "roman",
                          str(cut), "--refs", str(d / "roman_loop_refs"), "-o",
                          str(tmp_path / "out.asdf")], capture_output=True, text=True)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "cut_l1.asdf" in lines[0], res.stderr
    assert not (tmp_path / "out.asdf").exists()


def _refused_line(args, cwd):
    res = subprocess.run([sys.executable, "-m", "scenesim.cli", *args], cwd=cwd,
                         capture_output=True, text=True)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    return lines[0]


def test_pipeline_roman_refuses_the_truth_of_another_exposure_before_running(
        roman_loop, tmp_path):
    """The L1 records its exposure's SEED, SEEDENT, SCENEID and GAIN
    (meta.scenesim_cards); with its resultants, MA table, frame time and size they
    are compared with --truth before romancal runs (before: after the L2 was
    written, and an L1 carried nothing to tell two runs of one MA table apart)."""
    from astropy.io import fits
    from scenesim.pipelines.roman import l1_identity
    d, _ = roman_loop
    w = tmp_path / "w"
    w.mkdir()
    shutil.copy(d / "roman_loop_l1.asdf", w / "l1.asdf")
    shutil.copy(d / "roman_loop_truth.fits", w / "truth.fits")
    shutil.copytree(d / "roman_loop_refs", w / "refs")
    hdr, shape = l1_identity(w / "l1.asdf")
    truth_hdr = fits.getheader(w / "truth.fits")
    assert shape == (128, 128)
    for key in ("SEED", "SEEDENT", "SCENEID", "GAIN", "NGROUPS", "READPATT", "NINTS"):
        assert hdr[key] == truth_hdr[key], key
    for name, edit in (("seed", lambda h: h.update(SEED=2032)),
                       ("scene", lambda h: h.update(SCENEID="0123456789abcdef")),
                       ("gain", lambda h: h.update(GAIN=2.5)),
                       ("ngroups", lambda h: h.update(NGROUPS=5))):
        shutil.copy(w / "truth.fits", w / f"t_{name}.fits")
        with fits.open(w / f"t_{name}.fits", mode="update") as hdul:
            edit(hdul[0].header)
    before = {p: p.read_bytes() for p in w.rglob("*") if p.is_file()}
    for truth, words in (("t_seed.fits", ["'SEED' = 2031 in the L1", "2032 in the"]),
                         ("t_scene.fits", ["'SCENEID'", "'0123456789abcdef' in the"]),
                         ("t_gain.fits", ["'GAIN' = 2.0 in the L1", "2.5 in the"]),
                         ("t_ngroups.fits", ["'NGROUPS' = 6 in the L1", "5 in the"])):
        line = _refused_line(["pipeline", "roman", "l1.asdf", "--refs", "refs", "-o",
                              "l2.asdf", "--truth", truth], w)
        assert "not of the same exposure" in line and truth in line, line
        assert all(word in line for word in words), line
    assert {p: p.read_bytes() for p in w.rglob("*") if p.is_file()} == before
    assert not (w / "l2.asdf").exists()


def test_roman_reference_names_and_refs_errors(roman_loop, tmp_path):
    """Only roman_<type>.asdf of the writer's types are references (a backup
    roman_gain.asdf.bak was taken as the gain); a linearity without its inverse and
    a missing required type name '--refs' and the command that writes them."""
    from scenesim.pipelines.command import reference_paths
    d, _ = roman_loop
    refs = tmp_path / "refs"
    shutil.copytree(d / "roman_loop_refs", refs)
    for p in refs.glob("jwst_*"):
        p.unlink()
    written = reference_paths(refs, "roman")
    for stray in ("roman_gain.asdf.bak", "roman_gain.old.asdf", "roman_foo.asdf",
                  "roman_mask.fits", "jwst_gain.asdf"):
        (refs / stray).write_text("not a reference")
    assert reference_paths(refs, "roman") == written
    assert written["gain"] == os.path.join(str(refs), "roman_gain.asdf")
    shutil.copy(d / "roman_loop_l1.asdf", tmp_path / "l1.asdf")
    (refs / "roman_inverselinearity.asdf").unlink(missing_ok=True)
    shutil.copy(d / "roman_loop_refs" / "roman_gain.asdf",
                refs / "roman_linearity.asdf")
    line = _refused_line(["pipeline", "roman", "l1.asdf", "--refs", "refs", "-o",
                          "l2.asdf"], tmp_path)
    assert "'--refs'" in line and "roman_linearity.asdf" in line and \
        "roman_inverselinearity.asdf" in line, line
    (refs / "roman_mask.asdf").unlink()
    line = _refused_line(["pipeline", "roman", "l1.asdf", "--refs", "refs", "-o",
                          "l2.asdf"], tmp_path)
    assert "'--refs'" in line and "lacks ['roman_mask.asdf']" in line and \
        "scenesim run SCENE --reffiles" in line, line
    assert not (tmp_path / "l2.asdf").exists()
