"""The IRS2 uncal: the layout jwst's refpix step (IRS2 algorithm) reads, its reference
file, and jwst's step run offline on a simulated IRS2 exposure (needs the ``jwst``
extra; skipped without it).  IRS2 is full-frame only, so these use the full
NIRSPEC-IRS2 frame with few groups; the pipeline run itself is marked slow."""

import os

import numpy as np
import pytest

pytest.importorskip("stdatamodels")
pytest.importorskip("jwst")

from stdatamodels.jwst import datamodels as dm  # noqa: E402
from jwst.lib import pipe_utils  # noqa: E402
from jwst.refpix import irs2_subtract_reference as jirs2  # noqa: E402

import noise  # noqa: E402
from noise.clock import preset  # noqa: E402
from noise.errors import ParameterError  # noqa: E402
from scenesim.calib.prepare import PrepareOptions, fit_exposure_file  # noqa: E402
from scenesim.calib.refpix import correct_irs2  # noqa: E402
from scenesim.detector.readout import Readout  # noqa: E402
from scenesim.engine import ChargeEngine  # noqa: E402
from scenesim.io.exposure import Exposure, raw_resultants  # noqa: E402
from scenesim.pipelines import jwst  # noqa: E402
from scenesim.run import write_exposure  # noqa: E402

DET = preset("NIRSPEC-IRS2")


@pytest.fixture(scope="module")
def irs2_exposure(tmp_path_factory):
    d = tmp_path_factory.mktemp("irs2")
    eng = ChargeEngine(DET, Readout.named("NRSIRS2RAPID", ngroups=2),
                       noise_params=noise.NoiseParams(), rate=0.0, gain=1.0, rng=17)
    path = os.fspath(d / "x.fits")
    write_exposure(eng, path)
    uncal = jwst.write_uncal(path, os.fspath(d / "x_uncal.fits"))
    return d, path, uncal


def test_uncal_layout_is_jwsts(irs2_exposure):
    d, path, uncal = irs2_exposure
    exp = Exposure.read(path)
    raw = raw_resultants(exp, DET)
    with dm.RampModel(uncal, strict_validation=True) as m:
        assert m.data.shape == (1, 2, 3200, 2048)                   # DMS orientation
        assert pipe_utils.is_irs2(m)
        assert (m.meta.exposure.nrs_normal, m.meta.exposure.nrs_reference) == (16, 4)
        assert m.meta.exposure.readpatt == "NRSIRS2RAPID"
        assert m.meta.instrument.detector == "NRS1"
        assert (m.meta.subarray.fastaxis, m.meta.subarray.slowaxis) == (2, 1)
        # jwst's correct_model swaps NRS1 data back to detector orientation: ours
        det_orient = np.swapaxes(m.data, 2, 3)
        np.testing.assert_array_equal(det_orient, raw)
        # the normal/reference columns jwst's IRS2 mask expects
        mask = jirs2.make_irs2_mask(3200, 2048, 16, 4)
        _, _, image_x = DET.raw_columns()
        np.testing.assert_array_equal(mask, image_x >= 0)
        np.testing.assert_array_equal(det_orient[..., mask], exp.sci[..., image_x[mask]])


def test_irs2_frame_time():
    # JWST planning tools: IRS2 frames of 14.58889 s (NRSIRS2RAPID group 14.589 s,
    # NRSIRS2 72.944 s = 5 frames); the clock of whole rows is one pixel time shorter
    assert jwst.jwst_frame_time(DET) == pytest.approx(14.58889, abs=1e-8)
    assert DET.frame_time == pytest.approx(jwst.jwst_frame_time(DET) - 1e-5, abs=1e-9)
    assert 5 * jwst.jwst_frame_time(DET) == pytest.approx(72.944, abs=1e-3)


def test_nrs2_orientation():
    raw = np.arange(2 * 3 * 4).reshape(1, 2, 3, 4)
    dms = jwst.irs2_to_dms(raw, "NRS2")
    # jwst: NRS2 data -> np.swapaxes(data, 2, 3)[:, :, ::-1, ::-1]
    np.testing.assert_array_equal(np.swapaxes(dms, 2, 3)[:, :, ::-1, ::-1], raw)


def test_irs2_filter_passes_low_and_blocks_the_comb():
    beta = jwst.irs2_filter(DET)
    f = np.abs(np.fft.fftfreq(beta.size))
    gain = 712 / 256
    assert beta.size == 712 * 2048
    assert np.allclose(beta[f < 1 / 88], gain) and np.all(beta[f >= 1 / 44] == 0)


def test_bad_irs2_requests(irs2_exposure, tmp_path):
    d, path, uncal = irs2_exposure
    # an IRS2 uncal with the image-layout (non-IRS2) references: refused by name
    refs = {t: os.fspath(tmp_path / f"{t}.fits") for t in (
        "gain", "readnoise", "saturation", "superbias", "linearity", "dark", "mask")}
    with pytest.raises(ParameterError, match="IRS2 'refpix' reference"):
        jwst.run_detector1(uncal, refs, os.fspath(tmp_path))
    # ... and with a refpix reference but an image-layout (2048 x 2048) mask
    from astropy.io import fits
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(np.zeros((2048, 2048), np.uint8),
                                                   name="DQ")]).writeto(refs["mask"])
    refs["refpix"] = os.fspath(tmp_path / "refpix.fits")
    with pytest.raises(ParameterError, match="mask reference .* raw IRS2 layout"):
        jwst.run_detector1(uncal, refs, os.fspath(tmp_path))
    with pytest.raises(ParameterError, match="full 2048 x 2048 frame"):
        jwst.write_irs2_reference(DET.stripe(0, 64), os.fspath(tmp_path / "r.fits"))
    small = preset("NIRSPEC-IRS2", naxis1=256, naxis2=64)
    eng = ChargeEngine(small, Readout.named("NRSIRS2RAPID", ngroups=2), rng=1)
    out = write_exposure(eng, None)
    with pytest.raises(ParameterError, match="full 2048 x 2048 frame"):
        jwst.uncal_model(out["exposure"])


@pytest.mark.slow
def test_jwst_irs2_refpix_runs_offline_and_removes_correlated_noise(irs2_exposure):
    """jwst's refpix step (IRS2) with scenesim's reference file: it completes offline,
    and lowers the CDS noise of the regular pixels below the uncorrected one (by
    more than 5 sigma of the estimate), as scenesim's own 'irs2' does."""
    d, path, uncal = irs2_exposure
    ref = jwst.write_irs2_reference(DET, os.fspath(d / "jwst_refpix.fits"))
    exp = jwst.irs2_refpix_exposure(uncal, ref, path)
    raw = raw_resultants(Exposure.read(path), DET).astype(np.float64)[0]
    plain = Exposure.read(path).sci[0].astype(np.float64)
    reg = ~DET.reference_mask()
    v = {name: np.var((c[1] - c[0])[reg]) for name, c in (
        ("none", plain), ("jwst", exp.sci[0].astype(np.float64)),
        ("ours", correct_irs2(raw, DET, window=9)))}
    # relative standard error of a variance over n pixels: sqrt(2 / n) (neighbouring
    # pixels share their 1/f noise, so n is counted as one per 16 pixels: generous)
    tol = 5 * np.sqrt(2 / (reg.sum() / 16))
    assert v["jwst"] < v["none"] * (1 - tol)
    assert v["ours"] < v["none"] * (1 - tol)
    fit = fit_exposure_file(exp, os.fspath(d / "jw_gls.fits"), fitter="gls",
                            options=PrepareOptions(refpix="none"))
    assert fit is not None and os.path.exists(d / "jw_gls.fits")


ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SCENE = os.path.join(ROOT, "scenes", "nirspec_irs2.toml")


@pytest.fixture(scope="module")
def irs2_scene(tmp_path_factory):
    """scenes/nirspec_irs2.toml through the command line, once for this module: run
    (irs2 correction, GLS, compare), --uncal and --reffiles."""
    import subprocess
    import sys
    d = tmp_path_factory.mktemp("irs2_scene")
    res = subprocess.run(
        [sys.executable, "-m", "scenesim.cli", "run", SCENE, "-o", "irs2.fits",
         "--uncal", "--reffiles"], cwd=d, capture_output=True, text=True,
        env={**os.environ, "PYTHONPATH": ROOT})
    return d, res


@pytest.mark.slow
def test_example_scene_end_to_end(irs2_scene):
    """scenes/nirspec_irs2.toml through the command line: run (irs2 correction, GLS,
    compare), --uncal (jwst's layout, strict validation) and --reffiles (with the IRS2
    'refpix' reference file)."""
    d, res = irs2_scene
    assert res.returncode == 0, res.stderr
    assert "Slopes vs truth" in res.stdout
    with dm.RampModel(os.fspath(d / "irs2_uncal.fits"), strict_validation=True) as m:
        assert m.data.shape == (1, 4, 3200, 2048) and pipe_utils.is_irs2(m)
        # the image's size, as jwst's reffile_utils expects of IRS2 data
        assert (m.meta.subarray.xsize, m.meta.subarray.ysize) == (2048, 2048)
    with dm.IRS2Model(os.fspath(d / "irs2_refs" / "jwst_refpix.fits")) as r:
        assert len(r.irs2_table) == 2 * 712 * 2048


@pytest.mark.slow
def test_irs2_references_are_in_jwsts_layout(irs2_scene):
    """The references Detector1 meets before refpix are 3200 x 2048 in the DMS frame:
    jwst's own IRS2 extraction (saturation.x_irs2.from_irs2 with its make_mask) of the
    superbias and mask gives the detector's image bias and DQ in the DMS frame, and
    the samples it drops hold the reference samples' level (bias_offset) and the
    REFERENCE_PIXEL flag; the references after refpix are the image in the DMS
    frame."""
    from jwst.saturation import x_irs2
    from scenesim.detector.dq import REFERENCE_PIXEL
    from scenesim.pipelines.reffiles import detector_reference
    from scenesim.run import build_engine
    from scenesim.scene import load_scene
    d, res = irs2_scene
    assert res.returncode == 0, res.stderr
    scene = load_scene(SCENE)
    scene.ensure_seed()
    engine, _ = build_engine(scene)
    ref = detector_reference(scene, engine)
    g = ref.gain
    refs = d / "irs2_refs"
    with dm.RampModel(os.fspath(d / "irs2_uncal.fits")) as m:
        mask = x_irs2.make_mask(m)
    with dm.SuperBiasModel(os.fspath(refs / "jwst_superbias.fits")) as b:
        assert b.data.shape == (3200, 2048)
        np.testing.assert_allclose(x_irs2.from_irs2(b.data, mask, "NRS1"),
                                   (ref.bias / g).T, rtol=1e-6)
        np.testing.assert_allclose(b.data[~mask, :], ref.raw_level / g, rtol=1e-6)
    with dm.MaskModel(os.fspath(refs / "jwst_mask.fits")) as q:
        np.testing.assert_array_equal(x_irs2.from_irs2(q.dq, mask, "NRS1"), ref.mask.T)
        assert np.all(q.dq[~mask, :] == REFERENCE_PIXEL)
    with dm.SaturationModel(os.fspath(refs / "jwst_saturation.fits")) as s:
        np.testing.assert_allclose(s.data, (ref.saturation / g).T, rtol=1e-6)
        assert (s.meta.subarray.fastaxis, s.meta.subarray.slowaxis) == (2, 1)


@pytest.fixture(scope="module")
def irs2_detector1(irs2_scene):
    d, res = irs2_scene
    assert res.returncode == 0, res.stderr
    from scenesim.pipelines.command import reference_paths
    out = jwst.run_detector1(os.fspath(d / "irs2_uncal.fits"),
                             reference_paths(d / "irs2_refs", "jwst"), os.fspath(d / "d1"))
    return d, out


@pytest.mark.slow
def test_detector1_runs_offline_on_the_irs2_uncal(irs2_detector1):
    """jwst's whole Detector1 on the IRS2 uncal, offline, with scenesim's references:
    every step with a reference completes (refpix with its IRS2 algorithm), the rate
    is the 2048 x 2048 image in the DMS frame, and compare (which turns it back)
    finds the stars' fluxes and unbiased slopes."""
    from astropy.io import fits
    from scenesim.validate.compare import compare_files
    d, out = irs2_detector1
    hdr = fits.getheader(out["rate"])
    for key in ("S_DQINIT", "S_SATURA", "S_SUPERB", "S_REFPIX", "S_LINEAR", "S_DARK",
                "S_JUMP", "S_RAMP"):
        assert hdr[key] == "COMPLETE", key
    assert hdr["CRDS_CTX"] == jwst.OFFLINE_CONTEXT
    assert (hdr["FASTAXIS"], hdr["SLOWAXIS"]) == (2, 1)
    assert fits.getdata(out["rate"], "SCI").shape == (2048, 2048)
    report = compare_files(out["rate"], os.fspath(d / "irs2_truth.fits"),
                           exposure=os.fspath(d / "irs2.fits"))
    assert "subtracted the dark" in " ".join(report.notes)
    # the stars' aperture fluxes: the median ratio is 1 within 5 of its own standard
    # error (transposed or misplaced slopes would put the apertures on empty sky)
    ph = report.photometry
    assert ph["n"] >= 100
    assert abs(ph["median_ratio"] - 1) < 5 * ph["median_ratio_err"], ph
    # slopes of the star pixels (>= 1 e-/s, bins of >= 100 pixels) unbiased within 5
    # se_bias (se_bias counts one draw per output and 16 rows: correlated noise)
    graded = 0
    for row in report.rows:
        if row["n"] >= 100 and row["lo"] >= 1:
            graded += 1
            assert abs(row["bias_opt"]) < 5 * row["se_bias"], row
    assert graded >= 3
