"""Reading the pipelines' outputs for compare: the dark a JWST rate file lost, and the
step keywords (astropy only; no pipeline needed)."""

import numpy as np
from astropy.io import fits

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
    k = ipc_kernel(0.02)
    hdr = fits.Header({"IPC": True, "IPCKERN": ",".join(f"{v:.10g}" for v in k.ravel())})
    rate = np.full((8, 8), 10.0)
    dark = np.zeros((8, 8))
    dark[4, 4] = 5.0
    truth = {"header": hdr, "RATE": rate, "RATE_IPC": apply_ipc(rate, k)}
    out = subtract_dark(truth, dark)
    assert np.allclose(out["RATE"], rate - dark)
    assert np.allclose(out["RATE_IPC"], apply_ipc(rate, k) - apply_ipc(dark, k))
    assert truth["RATE"] is rate                    # the input is not changed


def test_jwst_step_keywords():
    hdr = fits.Header({"S_IPC": "COMPLETE", "S_DARK": "SKIPPED", "S_RAMP": "COMPLETE"})
    assert header_jwst_steps(hdr) == {"ipc", "ramp_fit"}
    assert header_ipc_deconvolved(hdr)
    assert not header_ipc_deconvolved(fits.Header({"S_IPC": "SKIPPED"}))
    assert header_ipc_deconvolved(fits.Header({"IPCDECON": True}))
