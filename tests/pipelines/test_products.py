"""Reading the pipelines' outputs for compare: the dark a JWST rate file lost, and the
step keywords (astropy only; no pipeline needed)."""

import numpy as np
from astropy.io import fits
import pytest

from scenesim.detector.ipc import apply_ipc, ipc_kernel
from scenesim.io.header import header_ipc_deconvolved, header_jwst_steps
from scenesim.pipelines.products import subtract_dark, subtracted_dark_rate


def _dark_file(path, rate_dn, ngroups, nframes, groupgap, t_frame):
    # group g averages frames k = g (nframes + groupgap) .. + nframes - 1, each
    # (k + 1) t_frame after the reset (rolling): the layout jwst.write_reference_files
    # writes
    k = np.array([np.mean(np.arange(g * (nframes + groupgap),
                                    g * (nframes + groupgap) + nframes) + 1.0)
                  for g in range(ngroups)])
    cube = (k[:, None, None] * t_frame * rate_dn[None]).astype(np.float32)
    hdr = fits.Header({"NFRAMES": nframes, "GROUPGAP": groupgap})
    fits.HDUList([fits.PrimaryHDU(header=hdr),
                  fits.ImageHDU(cube, name="SCI")]).writeto(path)


def test_dark_rate_from_the_reference_named_by_the_rate_file(tmp_path):
    rng = np.random.default_rng(4)
    rate_e = rng.uniform(0, 50, (16, 16))
    gain, t_frame = 2.0, 10.73676
    path = str(tmp_path / "dark.fits")
    _dark_file(path, rate_e / gain, ngroups=10, nframes=8, groupgap=2, t_frame=t_frame)
    hdr = fits.Header({"S_DARK": "COMPLETE", "R_DARK": path})
    dark, note = subtracted_dark_rate(hdr, t_frame, gain)
    # float32 storage: relative error ~1e-7 of the last group's charge
    assert np.allclose(dark, rate_e, rtol=1e-5, atol=1e-5)
    assert "subtracted the dark" in note


def test_no_dark_step_no_subtraction_and_missing_file_noted(tmp_path):
    assert subtracted_dark_rate(fits.Header(), 1.0, 1.0) == (None, "")
    hdr = fits.Header({"S_DARK": "COMPLETE", "R_DARK": str(tmp_path / "gone.fits")})
    dark, note = subtracted_dark_rate(hdr, 1.0, 1.0)
    assert dark is None and "not readable" in note


def test_subtract_dark_before_and_after_ipc():
    import noise
    k = ipc_kernel(0.02)
    det = noise.preset("H2RG", naxis1=8, naxis2=8, ref_border=2)
    hdr = fits.Header({"IPC": True, "IPCKERN": ",".join(f"{v:.10g}" for v in k.ravel())})
    for key, value, _ in det.to_header_cards():
        hdr[key] = value
    ref = det.reference_mask()
    rate = np.where(ref, 0.0, 10.0)
    dark = np.zeros((8, 8))
    dark[2, 4] = 5.0                                  # next to the reference rows
    truth = {"header": hdr, "RATE": rate, "RATE_IPC": apply_ipc(rate, k, refmask=ref)}
    out = subtract_dark(truth, dark)
    assert np.allclose(out["RATE"], rate - dark)
    # the pipeline's dark is seen through the same IPC, which leaves the reference
    # pixels alone: 2 % of 5 e-/s into each regular neighbour, none into row 1
    seen = apply_ipc(dark, k, refmask=ref)
    assert seen[1, 4] == 0.0 and np.isclose(seen[3, 4], 0.1) and np.isclose(seen.sum(), 5)
    assert np.allclose(out["RATE_IPC"], truth["RATE_IPC"] - seen)
    assert truth["RATE"] is rate                    # the input is not changed


def test_jwst_step_keywords():
    hdr = fits.Header({"S_IPC": "COMPLETE", "S_DARK": "SKIPPED", "S_RAMP": "COMPLETE"})
    assert header_jwst_steps(hdr) == {"ipc", "ramp_fit"}
    assert header_ipc_deconvolved(hdr)
    assert not header_ipc_deconvolved(fits.Header({"S_IPC": "SKIPPED"}))
    assert header_ipc_deconvolved(fits.Header({"IPCDECON": True}))


def _rate_file(path, slope_dn, var_dn, dq, header=None):
    """A JWST-layout rate file: SCI (DN/s), DQ, VAR_POISSON + VAR_RNOISE."""
    fits.HDUList([fits.PrimaryHDU(header=fits.Header(header or {})),
                  fits.ImageHDU(slope_dn.astype(np.float32), name="SCI"),
                  fits.ImageHDU(dq.astype(np.uint32), name="DQ"),
                  fits.ImageHDU((var_dn / 2).astype(np.float32), name="VAR_POISSON"),
                  fits.ImageHDU((var_dn / 2).astype(np.float32), name="VAR_RNOISE")]
                 ).writeto(path)


def test_slope_agreement_in_units_of_the_reference_errors(tmp_path):
    """product = reference + 0.5 sigma_ref everywhere, with twice its errors: mean
    and rms 0.5, error ratio 2; flagged and non-finite pixels left out; a dark the
    pipeline subtracted is taken out of the reference too."""
    from scenesim.pipelines.products import slope_agreement
    rng = np.random.default_rng(9)
    gain, t_frame, shape = 2.0, 10.73676, (16, 16)
    fits.PrimaryHDU(header=fits.Header({"GAIN": gain, "TFRAME": t_frame})).writeto(
        tmp_path / "exp.fits")
    ref = rng.uniform(0, 100, shape)                 # DN/s
    var = rng.uniform(0.5, 2.0, shape)               # (DN/s)^2
    dark_e = rng.uniform(0, 20, shape)               # e-/s
    dq = np.zeros(shape, dtype=np.uint32)
    dq[0, :4] = 1
    prod = ref + 0.5 * np.sqrt(var) - dark_e / gain
    prod[1, 1] = np.nan                # as Detector1 writes a pixel it cannot fit:
    pvar = 4 * var                      # NaN slope and variance
    pvar[1, 1] = np.nan
    _dark_file(str(tmp_path / "dark.fits"), dark_e / gain, ngroups=5, nframes=1,
               groupgap=0, t_frame=t_frame)
    _rate_file(tmp_path / "ref.fits", ref, var, np.zeros(shape))
    _rate_file(tmp_path / "rate.fits", prod, pvar, dq,
               {"S_DARK": "COMPLETE", "R_DARK": str(tmp_path / "dark.fits")})
    got = slope_agreement(str(tmp_path / "rate.fits"), str(tmp_path / "ref.fits"),
                          str(tmp_path / "exp.fits"))
    assert got["n"] == 16 * 16 - 4 - 1
    # float32 storage of slopes ~1e2 DN/s and of the dark: ~1e-5 sigma
    assert got["mean"] == pytest.approx(0.5, abs=1e-4)
    assert got["rms"] == pytest.approx(0.5, abs=1e-4)
    assert got["sigma_ratio"] == pytest.approx(2.0, rel=1e-6)
