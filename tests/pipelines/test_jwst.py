"""JWST: strict-valid uncal files of every example scene, strict-valid reference files,
and Detector1 run offline on a small subarray, graded by ``compare`` (needs the
``jwst`` extra; skipped without it)."""

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("stdatamodels")
pytest.importorskip("jwst")

from stdatamodels.jwst import datamodels as dm  # noqa: E402

from scenesim.io.exposure import read_exposure  # noqa: E402
from scenesim.pipelines import jwst  # noqa: E402
from scenesim.pipelines.command import reference_paths  # noqa: E402
from scenesim.validate.compare import compare_files  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
DATA = os.path.join(HERE, "..", "data", "pipelines")

# third-party warnings of the pipeline packages (not scenesim's): deprecations inside
# jwst/stpipe/asdf and numpy warnings of stcal on flagged pixels
pytestmark = [pytest.mark.filterwarnings("ignore::DeprecationWarning"),
              pytest.mark.filterwarnings("ignore::PendingDeprecationWarning"),
              pytest.mark.filterwarnings("ignore::RuntimeWarning"),
              pytest.mark.filterwarnings("ignore::UserWarning")]

SMALL = ("quick", "bright_star", "cosmic_rays", "transit")
LARGE_JWST = ("h2rg_starfield", "nirspec_dark")


def _scenesim(*args, cwd):
    res = subprocess.run([sys.executable, "-m", "scenesim.cli", *args], cwd=cwd,
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    return res.stdout


def _check_uncal(scene, tmp_path):
    _scenesim("run", os.path.join(ROOT, "scenes", f"{scene}.toml"), "-o",
              f"{scene}.fits", "--uncal", "-q", cwd=tmp_path)
    path = tmp_path / f"{scene}_uncal.fits"
    with dm.RampModel(str(path), strict_validation=True) as m:
        sci, hdr, _ = read_exposure(str(tmp_path / f"{scene}.fits"))
        # the resultants are the exposure's, unchanged
        assert np.array_equal(m.data, sci.astype(np.float32))
        assert m.meta.exposure.frame_time == hdr["TFRAME"]
        assert m.meta.exposure.ngroups == hdr["NGROUPS"]
        assert m.meta.exposure.nints == hdr["NINTS"]
        assert m.meta.exposure.drop_frames1 == hdr["DROPFRM1"]
        assert m.meta.exposure.frame_divisor == hdr["NFRAMES"]
        assert len(m.int_times) == hdr["NINTS"]
        assert m.meta.instrument.detector in ("NRCA1", "NRS1")
    # the uncal is also a scenesim exposure
    sci2, hdr2, reads2 = read_exposure(str(path))
    assert np.array_equal(sci2, sci) and hdr2["GAIN"] == hdr["GAIN"]


@pytest.mark.parametrize("scene", SMALL)
def test_example_scene_uncal_passes_strict_validation(scene, tmp_path):
    _check_uncal(scene, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("scene", LARGE_JWST)
def test_full_frame_scene_uncal_passes_strict_validation(scene, tmp_path):
    _check_uncal(scene, tmp_path)


def test_h4rg_has_no_jwst_uncal(tmp_path):
    from scenesim.scene import load_scene
    from scenesim.run import build_engine
    scene = load_scene(os.path.join(DATA, "roman_loop.toml"))
    engine, _ = build_engine(scene)
    from noise.errors import ParameterError
    from scenesim.pipelines.reffiles import detector_reference
    with pytest.raises(ParameterError, match="Roman L1"):
        jwst.write_reference_files(detector_reference(scene, engine), engine.readout,
                                   engine.detector.frame_time, tmp_path / "r")


@pytest.fixture(scope="module")
def jwst_loop(tmp_path_factory):
    """The CI loop: run (uncal + references), then Detector1 offline."""
    d = tmp_path_factory.mktemp("jwst_loop")
    shutil.copy(os.path.join(DATA, "jwst_loop.toml"), d)
    _scenesim("run", "jwst_loop.toml", "--uncal", "--reffiles", "-q", cwd=d)
    out = jwst.run_detector1(str(d / "jwst_loop_uncal.fits"),
                             reference_paths(d / "jwst_loop_refs", "jwst"), str(d))
    return d, out


def test_reference_files_pass_strict_validation(jwst_loop):
    d, _ = jwst_loop
    refs = reference_paths(d / "jwst_loop_refs", "jwst")
    assert set(refs) >= set(jwst.REFERENCE_TYPES)
    for path in refs.values():
        if path.endswith(".fits"):
            with dm.open(path, strict_validation=True) as m:
                assert m.meta.author == "scenesim"


def test_detector1_runs_offline_and_compare_grades_it(jwst_loop):
    d, out = jwst_loop
    from astropy.io import fits
    hdr = fits.getheader(out["rate"])
    for key in ("S_DQINIT", "S_SATURA", "S_IPC", "S_SUPERB", "S_REFPIX", "S_LINEAR",
                "S_DARK", "S_JUMP", "S_RAMP"):
        assert hdr[key] == "COMPLETE", key
    assert hdr["CRDS_CTX"] == jwst.OFFLINE_CONTEXT
    report = compare_files(out["rate"], str(d / "jwst_loop_truth.fits"),
                           exposure=str(d / "jwst_loop.fits"))
    notes = " ".join(report.notes)
    assert "subtracted the dark" in notes and "undid IPC" in notes
    # every unsaturated flux bin holding >= 10 pixels: the pipeline's slopes are
    # unbiased and its errors right, within what 1/f noise and one exposure allow
    # (1 sigma of bias: se_bias is ~0.2-0.3 here; chi2 within 0.6..1.7)
    graded = 0
    for row in report.rows:
        if row["n"] >= 10 and row["lo"] < 1e4:
            graded += 1
            assert abs(row["bias_rep"]) < 1.0, row
            assert 0.6 < row["chi2_rep"] < 1.7, row
    assert graded >= 3
    # the bright star: aperture photometry within 1 %
    assert report.photometry["median_ratio"] == pytest.approx(1.0, abs=0.01)


def test_rateints_combine_to_the_rate(jwst_loop):
    """A rateints file graded like the rate file: inverse-variance combination of the
    integrations, the same bins to a few thousandths of sigma (saturated pixels
    aside, which Detector1 combines over their usable groups instead)."""
    d, out = jwst_loop
    kw = dict(exposure=str(d / "jwst_loop.fits"))
    rate = compare_files(out["rate"], str(d / "jwst_loop_truth.fits"), **kw)
    ints = compare_files(out["rateints"], str(d / "jwst_loop_truth.fits"), **kw)
    assert "fit layout: jwst-rateints" in ints.notes
    compared = 0
    for a, b in zip(rate.rows, ints.rows):
        # bins holding flagged pixels around the saturated star (frac_flagged 0.2 in
        # the 100-1e4 e-/s bins of 14-24 pixels) are left out: there one pixel whose
        # integrations saturate differently moves the bin by ~0.1 sigma, the
        # difference the docstring names; the faint bins' few flags (hot pixels,
        # jumps: 1.3 % of 3510 pixels) are combined alike
        if a["n"] >= 10 and a["lo"] < 1e4 and a["frac_flagged"] < 0.05:
            assert b["n"] == a["n"]
            assert b["frac_flagged"] == a["frac_flagged"]
            # a flagged pixel's r/sigma may differ by ~1 between the two
            # combinations (saturated in some integrations only): its share of the
            # bin, frac_flagged, is allowed on top (the hot pixels drawn for the full
            # array since 2026-11-28 put one flagged pixel in a 24-pixel bin, 0.016)
            tol = 0.01 + a["frac_flagged"]
            assert abs(b["bias_rep"] - a["bias_rep"]) < tol
            assert abs(b["chi2_rep"] / a["chi2_rep"] - 1) < tol
            compared += 1
    assert compared >= 2


def test_pipeline_command_prints_the_report(jwst_loop):
    d, _ = jwst_loop
    text = _scenesim("pipeline", "jwst", "jwst_loop_uncal.fits", "--refs",
                     "jwst_loop_refs", "-o", "again", "--truth", "jwst_loop_truth.fits",
                     "--exposure", "jwst_loop.fits", cwd=d)
    assert "Slopes vs truth" in text and "fit layout: jwst" in text
    assert os.path.exists(d / "again" / "jwst_loop_rate.fits")


ZERO_SCENE = """seed = 8
[detector]
preset = "NIRCAM"
nfoh = 2
[detector.subarray]
kind = "window"
x0 = 0
y0 = 0
nx = 32
ny = 32
[readout]
pattern = "BRIGHT2"
ngroups = 4
nints = 2
[sources]
background = 20.0
[[sources.stars]]
x = 16.3
y = 15.6
flux = 2e6
[effects]
full_well = 8e4
gain = 2.0
[output]
path = "zf.fits"
"""


def test_nircam_frame_averaged_uncal_has_its_zero_frame(tmp_path):
    """BRIGHT2 on NIRCam: the uncal carries ZEROFRAME (the first read of each
    integration) and ZEROFRAM = T, passes strict validation, and Detector1 runs on
    it with the zero frame through saturation, superbias and refpix."""
    (tmp_path / "zf.toml").write_text(ZERO_SCENE)
    _scenesim("run", "zf.toml", "--uncal", "--reffiles", "-q", cwd=tmp_path)
    sci, hdr, _ = read_exposure(str(tmp_path / "zf.fits"))
    with dm.RampModel(str(tmp_path / "zf_uncal.fits"), strict_validation=True) as m:
        assert m.meta.exposure.zero_frame is True
        assert m.meta.exposure.frame_divisor == 2 == m.meta.exposure.nframes
        zero = np.asarray(m.zeroframe)
    assert zero.shape == (2, 32, 32)
    # group 1 averages reads 1 and 2 (in frame times after the reset), the zero frame
    # is read 1: away from the star, group 1 - zero frame = half a frame of charge
    det = hdr["TFRAME"]
    live = np.ones((32, 32), dtype=bool)
    live[:4] = live[-4:] = False
    live[:, :4] = live[:, -4:] = False
    live[10:23, 10:23] = False
    d = sci[:, 0].astype(np.float64)[:, live] - zero[:, live]
    # background 20 e-/s: 0.5 t_frame x 20 / gain = 0.07 DN; read noise of the
    # difference of one read and a two-read mean: sqrt(5^2 + 5^2/2 + ...)/2 ~ 3.5 DN
    # per pixel; 2 x 576 pixels, 1/f partly common: 5 x 3.5 / sqrt(1152) x 3
    assert abs(d.mean() - 0.5 * det * 20 / 2) < 5 * 3.5 / np.sqrt(d.size) * 3
    out = jwst.run_detector1(str(tmp_path / "zf_uncal.fits"),
                             reference_paths(tmp_path / "zf_refs", "jwst"),
                             str(tmp_path))
    from astropy.io import fits
    assert fits.getheader(out["rate"])["S_RAMP"] == "COMPLETE"


def test_subarray_names_come_from_the_jwst_lists(tmp_path):
    """A JWST subarray name is kept (and strict-valid); one JWST does not know is
    refused in one line before the run, not silently dropped by the models."""
    assert jwst.check_subarray_name("SUB64P") == "SUB64P"
    from noise.errors import ParameterError
    with pytest.raises(ParameterError, match="'STRIPE128' is not a JWST SUBARRAY"):
        jwst.check_subarray_name("STRIPE128")
    base = open(os.path.join(DATA, "jwst_loop.toml")).read()
    for name, ok in (("SUB64P", True), ("STRIPE128", False)):
        (tmp_path / f"{name}.toml").write_text(
            base + f'[instrument]\nname = "NIRCAM"\nsubarray = "{name}"\n')
        res = subprocess.run([sys.executable, "-m", "scenesim.cli", "run",
                              f"{name}.toml", "-o", f"{name}.fits", "--uncal", "-q"],
                             cwd=tmp_path, capture_output=True, text=True)
        if ok:
            assert res.returncode == 0, res.stderr
            with dm.RampModel(str(tmp_path / f"{name}_uncal.fits"),
                              strict_validation=True) as m:
                assert m.meta.subarray.name == "SUB64P"
        else:
            assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1
            assert not (tmp_path / f"{name}.fits").exists()


def test_frame_keywords_and_int_times_against_the_clock(tmp_path):
    """nframes 2, groupgap 1, 2 frames dropped after reset, 3 groups, 2 integrations:
    DRPFRMS1 = 2, FRMDIVSR = NFRAMES = 2, TGROUP = 3 t_frame; each integration is its
    reset frame plus nreads = 2 + 2 x 3 + 2 = 10 frames, so INT_TIMES steps by 11
    t_frame and spans 11 t_frame (MJD days)."""
    from scenesim.run import build_engine, write_exposure
    from scenesim.scene import parse_scene
    scene = parse_scene({
        "seed": 4, "detector": {"preset": "NIRCAM", "nfoh": 2, "subarray": {
            "kind": "window", "x0": 0, "y0": 0, "nx": 16, "ny": 16}},
        "readout": {"nframes": 2, "ngroups": 3, "groupgap": 1, "nskip": 2,
                    "nints": 2},
        "output": {"path": "x.fits", "truth": False}})
    engine, _ = build_engine(scene)
    exp = write_exposure(engine, None)["exposure"]
    path = str(tmp_path / "x_uncal.fits")
    jwst.write_uncal(exp, path)
    t = engine.detector.frame_time
    with dm.RampModel(path, strict_validation=True) as m:
        ex = m.meta.exposure
        assert (ex.drop_frames1, ex.frame_divisor, ex.nframes, ex.groupgap) == (2, 2, 2, 1)
        assert ex.group_time == pytest.approx(3 * t, rel=1e-12)
        assert ex.zero_frame is False          # from a file alone: no zero frame
        it = m.int_times
        day = 86400.0
        start = np.asarray(it["int_start_MJD_UTC"])
        end = np.asarray(it["int_end_MJD_UTC"])
    # MJD near 6e4 days in float64: ~1e-11 d = 1 us resolution
    assert np.allclose((start[1] - start[0]) * day, 11 * t, atol=1e-5)
    assert np.allclose((end - start) * day, 11 * t, atol=1e-5)
    from astropy.io import fits
    hdr = fits.getheader(path)
    assert hdr["DRPFRMS1"] == 2 and hdr["FRMDIVSR"] == 2
    # EFFEXPTM and XPOSURE (both "effective exposure time" in the schema) =
    # EFFINTTM x NINTS; DURATION the whole span, 2 x 11 frames (before, EFFEXPTM was
    # the duration)
    with dm.RampModel(path) as m:
        ex = m.meta.exposure
        assert ex.exposure_time == pytest.approx(ex.integration_time * 2, rel=1e-12)
        assert ex.effective_exposure_time == pytest.approx(ex.exposure_time, rel=1e-12)
        assert ex.duration == pytest.approx(22 * t, rel=1e-9)
    assert hdr["EFFEXPTM"] == pytest.approx(hdr["EFFINTTM"] * 2, rel=1e-12)


def _refused(args, cwd):
    res = subprocess.run([sys.executable, "-m", "scenesim.cli", *args], cwd=cwd,
                         capture_output=True, text=True)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    return lines[0]


def _digest(directory):
    return {os.path.relpath(os.path.join(r, n), directory):
            open(os.path.join(r, n), "rb").read() for r, _, ns in os.walk(directory)
            for n in ns}


def test_pipeline_jwst_never_replaces_an_input_and_checks_first(jwst_loop, tmp_path):
    """Detector1 names its products from the input without its one pipeline suffix:
    an uncal named x_rate.fits has the product x_rate.fits.  That product, an
    existing one without --overwrite, a missing or wrong input, a missing --truth, an
    -o that is a file: each refused in one line before the pipeline runs, nothing
    changed or created."""
    d, _ = jwst_loop
    w = tmp_path / "w"
    w.mkdir()
    shutil.copy(d / "jwst_loop_uncal.fits", w / "z_rate.fits")
    shutil.copy(d / "jwst_loop_uncal.fits", w / "v_ramp.fits")
    (w / "v_rate.fits").write_text("mine")
    (w / "file").write_text("mine")
    shutil.copytree(d / "jwst_loop_refs", w / "refs")
    shutil.copy(d / "jwst_loop.fits", w / "exposure.fits")
    # references of another run: another gain, another array size
    from astropy.io import fits
    shutil.copytree(d / "jwst_loop_refs", w / "refs_gain")
    with fits.open(w / "refs_gain" / "jwst_gain.fits", mode="update") as hdul:
        hdul["SCI"].data = hdul["SCI"].data * np.float32(1.1)
    shutil.copytree(d / "jwst_loop_refs", w / "refs_size")
    with fits.open(w / "refs_size" / "jwst_superbias.fits", mode="update") as hdul:
        hdul["SCI"].data = hdul["SCI"].data[:-2]
    # the same detector, size and gain, but another run's dark (its reference id:
    # test_reffiles.test_reference_id_follows_the_hot_pixels_not_the_seed)
    assert fits.getval(d / "jwst_loop_uncal.fits", "SSREFID") == \
        fits.getval(d / "jwst_loop_refs" / "jwst_dark.fits", "SSREFID")
    shutil.copytree(d / "jwst_loop_refs", w / "refs_run")
    with fits.open(w / "refs_run" / "jwst_dark.fits", mode="update") as hdul:
        hdul[0].header["SSREFID"] = "0123456789abcdef"
    before = _digest(w)
    for args, words in (
            (["z_rate.fits", "--overwrite"], ["z_rate.fits", "reads"]),
            (["v_ramp.fits"], ["v_rate.fits", "exists"]),
            (["nope.fits"], ["nope.fits", "does not exist"]),
            (["exposure.fits"], ["not a JWST level-1b"]),
            (["z_rate.fits", "-o", "file"], ["'file' is a file"]),
            (["z_rate.fits", "-o", "new", "--truth", "nope.fits"], ["'--truth'"]),
            # a truth of the wrong kind (before: found after the rate files were
            # written)
            (["z_rate.fits", "-o", "new", "--truth", "exposure.fits"],
             ["truth", "exposure.fits"]),
            # references of another run (before: ran without a word, or failed
            # inside jwst with a traceback)
            (["z_rate.fits", "-o", "new", "--refs", "refs_gain"],
             ["gain reference", "GAIN"]),
            (["z_rate.fits", "-o", "new", "--refs", "refs_size"],
             ["superbias reference", "pixels"]),
            (["z_rate.fits", "-o", "new", "--refs", "refs_run"],
             ["dark reference", "another run's detector", "0123456789abcdef"])):
        if "--refs" not in args:
            args = [*args, "--refs", "refs"]
        line = _refused(["pipeline", "jwst", *args], w)
        assert all(word in line for word in words), line
    assert _digest(w) == before and not (w / "new").exists()


def test_run_products_never_replace_a_file_the_scene_reads(tmp_path):
    """--uncal and --reffiles with --overwrite: a product that is one of the scene's
    inputs (its catalogue named x_uncal.fits, its flat inside the reference
    directory) is refused before the run, and a reference 'directory' that is a file
    too; nothing changes."""
    from astropy.io import fits
    from astropy.table import Table
    Table({"x": [10.0], "y": [10.0], "flux": [100.0]}).write(tmp_path / "x_uncal.fits")
    (tmp_path / "y_refs").mkdir()
    fits.writeto(tmp_path / "y_refs" / "jwst_gain.fits", np.ones((32, 32)))
    (tmp_path / "m_refs").write_text("a file")
    base = ('seed = 1\n[detector]\npreset = "H2RG"\nnaxis1 = 32\nnaxis2 = 32\n'
            '[readout]\npattern = "RAPID"\nngroups = 3\n[output]\npath = "{p}"\n'
            '[sources]\n')
    (tmp_path / "s.toml").write_text(base.format(p="x.fits")
                                     + 'catalogue = "x_uncal.fits"\n')
    (tmp_path / "t.toml").write_text(base.format(p="y.fits") + "[effects]\n"
                                     'flat = "y_refs/jwst_gain.fits"\n')
    (tmp_path / "u.toml").write_text(base.format(p="m.fits"))
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    for scene, product, words in (("s.toml", "--uncal", ["x_uncal.fits", "reads"]),
                                  ("t.toml", "--reffiles", ["jwst_gain.fits", "reads"]),
                                  ("u.toml", "--reffiles", ["'m_refs' is a file"])):
        res = subprocess.run([sys.executable, "-m", "scenesim.cli", "run", scene, product,
                              "--overwrite", "-q"], cwd=tmp_path, capture_output=True,
                             text=True)
        assert res.returncode == 2, res.stderr
        lines = res.stderr.strip().splitlines()
        assert len(lines) == 1 and all(w in lines[0] for w in words), res.stderr
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


def test_a_subarray_name_must_fit_the_readout():
    """A 32 x 32 window said SUB640 (a 640 x 640 NIRCam subarray) and FULL could name
    a window; a full frame may carry any full-frame name (FULLP: a probe found it
    refused by the first version of this check)."""
    from noise.clock import Subarray, preset
    from noise.errors import ParameterError
    full = preset("NIRCAM")
    win = preset("NIRCAM", subarray=Subarray("window", 0, 0, 32, 32))
    sub64 = preset("NIRCAM", subarray=Subarray("window", 0, 0, 64, 64))
    for name, det in (("FULL", full), ("FULLP", full), ("GENERIC", win),
                      ("SUB64P", sub64), ("GENERIC", full)):
        assert jwst.check_subarray_name(name, det, "NIRCAM") == name
    for name, det, words in (("SUB640", win, "is a 640 x 640 subarray"),
                             ("SUB64P", win, "is a 64 x 64 subarray"),
                             ("FULL", win, "is a full-frame name"),
                             ("FULLP", win, "is a full-frame name"),
                             ("SUB64P", full, "names a subarray, but the readout is "
                                              "the full")):
        with pytest.raises(ParameterError, match=words):
            jwst.check_subarray_name(name, det, "NIRCAM")


def test_a_readout_that_is_not_multiaccum_has_no_uncal(tmp_path):
    # A probe's explicit reads [[0], [2], [3], [9]] were written as NFRAMES 1,
    # GROUPGAP 1, TGROUP 3 frames, and jwst's ramp fit found 974.7 e-/s for 1000
    # (-2.5 %, 18 sigma).  Refused before the run (nothing written), and by the
    # library's writer.
    import os
    import subprocess
    import sys
    scene = tmp_path / "n6.toml"
    scene.write_text(
        'seed = 1\n[detector]\nnaxis1 = 64\nnaxis2 = 64\n[noise]\npreset = "none"\n'
        '[readout]\nresultants = [[0], [2], [3], [9]]\n[sources]\ndark_current = 1000.0\n'
        '[output]\npath = "n6.fits"\n')
    res = subprocess.run([sys.executable, "-m", "scenesim.cli", "run", "n6.toml",
                          "--uncal", "-q"], cwd=tmp_path, capture_output=True, text=True)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "--uncal" in lines[0] and "MULTIACCUM" in lines[0]
    assert sorted(os.listdir(tmp_path)) == ["n6.toml"]
    res = subprocess.run([sys.executable, "-m", "scenesim.cli", "run", "n6.toml", "-q"],
                         cwd=tmp_path, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    from noise.errors import ParameterError
    from scenesim.pipelines.jwst import write_uncal
    with pytest.raises(ParameterError, match="MULTIACCUM"):
        write_uncal(tmp_path / "n6.fits", tmp_path / "u.fits")
    assert not (tmp_path / "u.fits").exists()


def test_an_exp_type_must_be_of_the_inferred_instrument():
    """With no [instrument] name the instrument is inferred (from the detector or the
    readout); an exp_type of another instrument was written beside it (INSTRUME =
    NIRCAM, EXP_TYPE = MIR_IMAGE)."""
    from noise.clock import preset
    from noise.errors import ParameterError
    from scenesim.pipelines.instrument import InstrumentConfig, resolve_instrument
    det = preset("NIRCAM")
    ok = resolve_instrument(InstrumentConfig(exp_type="NRC_TSIMAGE"), det, "RAPID")
    assert ok["name"] == "NIRCAM" and ok["exp_type"] == "NRC_TSIMAGE"
    with pytest.raises(ParameterError, match=r"'MIR_IMAGE' is not a NIRCAM exposure "
                                             r"type.*inferred from the readout.*'NRC_'"):
        resolve_instrument(InstrumentConfig(exp_type="MIR_IMAGE"), det, "RAPID")
    with pytest.raises(ParameterError, match=r"not a NIRSPEC exposure type.*of detector "
                                             r"'NRS1'"):
        resolve_instrument(InstrumentConfig(detector="NRS1", exp_type="NRC_IMAGE"),
                           preset("NIRSPEC"), "NRSRAPID")
    # the instrument of NIRSpec's dropped-frame and NIRISS's patterns (a probe: a
    # NIRISS uncal read RAPID, the NIRCam pattern, for want of NIS/NISRAPID)
    for pattern, name, detector in (("NRSRAPIDD6", "NIRSPEC", "NRS1"),
                                    ("NIS", "NIRISS", "NIS"),
                                    ("NISRAPID", "NIRISS", "NIS")):
        got = resolve_instrument(InstrumentConfig(), det, pattern)
        assert (got["name"], got["detector"], got["readpatt"]) == (name, detector,
                                                                    pattern)


def test_pipeline_jwst_refuses_the_truth_of_another_exposure_before_running(jwst_loop,
                                                                           tmp_path):
    """--truth of another exposure was found only after Detector1 had run and written
    the rate files ('NINTS' = 2 in the slope file, 1 in the truth file).  Now the
    uncal's identity cards (NINTS, SEED, SCENEID, GAIN ... as the rate file would
    carry them) and its size are compared with the truth before the pipeline: one
    line naming the card and both values, nothing written."""
    from astropy.io import fits
    d, _ = jwst_loop
    w = tmp_path / "w"
    w.mkdir()
    for name in ("jwst_loop_uncal.fits", "jwst_loop_truth.fits", "jwst_loop.fits"):
        shutil.copy(d / name, w / name)
    shutil.copytree(d / "jwst_loop_refs", w / "refs")
    # another run of the same scene file: one integration, another seed
    with open(os.path.join(DATA, "jwst_loop.toml")) as f:
        text = f.read()
    assert "seed = 77" in text and "nints = 2" in text
    (w / "b.toml").write_text(text.replace("seed = 77", "seed = 78")
                              .replace("nints = 2", "nints = 1")
                              .replace('"jwst_loop.fits"', '"b.fits"'))
    _scenesim("run", "b.toml", "-q", cwd=w)
    # the truth of A with one identity card (or its size) changed
    for name, edit in (("seed", lambda h: h.update(SEED=78)),
                       ("scene", lambda h: h.update(SCENEID="0123456789abcdef")),
                       ("gain", lambda h: h.update(GAIN=2.5))):
        shutil.copy(w / "jwst_loop_truth.fits", w / f"t_{name}.fits")
        with fits.open(w / f"t_{name}.fits", mode="update") as hdul:
            edit(hdul[0].header)
    shutil.copy(w / "jwst_loop_truth.fits", w / "t_size.fits")
    with fits.open(w / "t_size.fits", mode="update") as hdul:
        for ext in ("RATE", "RATE_IPC"):
            hdul[ext].data = hdul[ext].data[:32]
    before = _digest(w)
    for truth, words in (
            ("b_truth.fits", ["uncal", "b_truth.fits", "'NINTS' = 2 in the uncal",
                              "1 in the truth file"]),
            ("t_seed.fits", ["'SEED' = 77 in the uncal", "78 in the truth file"]),
            ("t_scene.fits", ["'SCENEID'", "'0123456789abcdef' in the truth file"]),
            ("t_gain.fits", ["'GAIN' = 2.0 in the uncal", "2.5 in the truth file"]),
            ("t_size.fits", ["the uncal is 64 x 64 pixels", "the truth file 32 x 64"])):
        line = _refused(["pipeline", "jwst", "jwst_loop_uncal.fits", "--refs", "refs",
                         "-o", "new", "--truth", truth], w)
        assert "not of the same exposure" in line and all(
            word in line for word in words), line
    # an --exposure of the truth's run does not make another run's uncal acceptable
    line = _refused(["pipeline", "jwst", "jwst_loop_uncal.fits", "--refs", "refs",
                     "-o", "new", "--truth", "b_truth.fits", "--exposure", "b.fits"], w)
    assert "'NINTS' = 2 in the uncal" in line, line
    assert _digest(w) == before and not (w / "new").exists()


def test_reference_paths_takes_only_the_names_the_writer_gives(jwst_loop, tmp_path):
    """A backup jwst_dark.fits.bak sorted after jwst_dark.fits and was taken as the
    dark; now only jwst_<type>.fits of the writer's types are references."""
    d, _ = jwst_loop
    refs = tmp_path / "refs"
    shutil.copytree(d / "jwst_loop_refs", refs)
    written = reference_paths(refs, "jwst")
    for stray in ("jwst_dark.fits.bak", "jwst_gain.fits~", "jwst_dark.old.fits",
                  "jwst_foo.fits", "jwst_mask.fits.gz", "jwst_mask.asdf",
                  "roman_gain.fits"):
        (refs / stray).write_text("not a reference")
    found = reference_paths(refs, "jwst")
    assert found == written
    assert found["dark"] == os.path.join(str(refs), "jwst_dark.fits")
    assert {os.path.basename(p) for p in found.values()} == \
        {f"jwst_{t}.fits" for t in found}
    assert set(found) <= set(jwst.REFERENCE_TYPES) | {"refpix"}


def test_pipeline_refs_errors_name_the_option_and_the_cure(jwst_loop, tmp_path):
    """--refs that does not exist, is a file, holds no references or lacks some:
    four distinct lines naming '--refs', the value and 'scenesim run ... --reffiles'
    (before: 'holds no jwst_<type> reference files' for the first two, and the API's
    "'references' lacks [...]; write them with write_reference_files"); an IRS2
    uncal without jwst_refpix.fits names it too."""
    from astropy.io import fits
    d, _ = jwst_loop
    w = tmp_path / "w"
    w.mkdir()
    shutil.copy(d / "jwst_loop_uncal.fits", w / "u_uncal.fits")
    (w / "empty").mkdir()
    (w / "partial").mkdir()
    for t in ("gain", "readnoise", "dark"):
        shutil.copy(d / "jwst_loop_refs" / f"jwst_{t}.fits", w / "partial")
    (w / "partial" / "jwst_mask.fits.bak").write_text("a backup")
    shutil.copytree(d / "jwst_loop_refs", w / "refs")
    shutil.copy(d / "jwst_loop_uncal.fits", w / "irs2_uncal.fits")
    with fits.open(w / "irs2_uncal.fits", mode="update") as hdul:
        hdul[0].header["NRS_NORM"] = 16
    before = _digest(w)
    lines = []
    for refs, words in (("nosuchdir", ["'nosuchdir'", "does not exist"]),
                        ("u_uncal.fits", ["'u_uncal.fits'", "is a file"]),
                        ("empty", ["'empty'", "holds no jwst reference files"]),
                        ("partial", ["'partial'", "lacks", "'jwst_saturation.fits'",
                                     "'jwst_mask.fits'"])):
        line = _refused(["pipeline", "jwst", "u_uncal.fits", "--refs", refs, "-o",
                         "new"], w)
        assert "'--refs'" in line and "scenesim run SCENE --reffiles" in line, line
        assert all(word in line for word in words), line
        assert "write_reference_files" not in line and "'references'" not in line
        lines.append(line)
    assert len(set(lines)) == 4
    assert "'jwst_gain.fits'" not in lines[-1]
    line = _refused(["pipeline", "jwst", "irs2_uncal.fits", "--refs", "refs", "-o",
                     "new"], w)
    assert "IRS2" in line and "jwst_refpix.fits" in line and "'--refs'" in line, line
    assert _digest(w) == before and not (w / "new").exists()
