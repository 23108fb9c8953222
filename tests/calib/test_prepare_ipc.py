"""Undoing IPC before the nonlinearity is inverted (:mod:`scenesim.calib.prepare`).

The inverse itself is tested in ``tests/detector/test_ipc_inverse.py``.

The engine makes every read ``F * K(p(q))``: the charge ``q`` since reset, the
classical nonlinearity ``p(q) = q + c2 q^2 + c3 q^3``, the 3x3 IPC convolution ``K``
(charge whose target is off the array stays in its pixel), the flat ``F`` (none
here).  ``K`` is linear, so ``K^-1`` of a resultant is the mean of ``p(q)`` over its
reads, and inverting ``p`` then gives the pixel's own charge; inverting ``p`` on the
IPC-mixed signal instead mixes ``p`` of neighbours with different charges, which
biased the bright-star slopes by -0.3 sigma.

References used here, independent of the code under test:

* ``K`` as a dense matrix built from the rule above (``out[y + dy, x + dx] +=
  k[1 + dy, 1 + dx] * x[y, x]``, off-array targets kept) and solved with
  ``numpy.linalg.solve``;
* the white-noise gain of ``K^-1`` from its Fourier transform, ``g^2 = mean_k
  |1 / K(k)|^2``;
* ramps simulated here (noise-free) or by the engine (noisy) from a rate map, with the
  rate map itself as the truth: after ``K^-1`` a fit recovers each pixel's own rate.
"""

import numpy as np
import pytest
from astropy.io import fits

import noise
from noise.clock import preset
from ipc_theory import ipc_matrix
from noise.errors import FileFormatError, ParameterError
from scenesim.detector.nonlinearity import Nonlinearity
from scenesim.detector.ipc import ipc_kernel
from scenesim.engine import ChargeEngine, EngineOptions
from scenesim.io.exposure import read_exposure
from scenesim.run import write_exposure
from scenesim.detector.dq import SATURATED
from scenesim.rampfit import fit_ramps
from scenesim.calib.prepare import PrepareOptions, fit_exposure_file, prepare_exposure
from scenesim.calib.saturation import SaturationOptions, saturation_flags
from scenesim.io.header import header_ipc_kernel
from scenesim.detector.ipc import ipc_noise_gain, undo_ipc
from scenesim.detector.nonlinearity import linearize_resultants
from scenesim.detector.readout import Readout


C2, C3 = -8e-7, -2e-12          # nonlinearity of the bright-star scene (e-^-1, e-^-2)
FW = 8e4                        # e-
ALPHA = 0.015
#: An asymmetric kernel with diagonal terms (sums to 1)
GENERAL = np.array([[0.002, 0.012, 0.003],
                    [0.020, 0.944, 0.010],
                    [0.001, 0.006, 0.002]])


def p(q):
    return q + C2 * q ** 2 + C3 * q ** 3


def star(shape, centres, core):
    """Rate map (e-/s): cores ``core``, nearest neighbours 0.4 core, diagonals 0.15
    core, on 2 e-/s."""
    rate = np.full(shape, 2.0)
    for (y, x), f in zip(centres, core):
        rate[y - 1:y + 2, x - 1:x + 2] += f * np.array([[0.15, 0.4, 0.15],
                                                         [0.4, 1.0, 0.4],
                                                         [0.15, 0.4, 0.15]])
    return rate


def core_and_neighbours(centres):
    ys, xs = [], []
    for y, x in centres:
        for dy, dx in ((0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)):
            ys.append(y + dy)
            xs.append(x + dx)
    return np.array(ys), np.array(xs)


def _small_engine(kernel, **kw):
    det = preset("H2RG", naxis1=32, naxis2=32)
    ro = Readout.multiaccum(1, 4, name="RAPID")
    rate = np.where(det.reference_mask(), 0.0, 50.0)
    return ChargeEngine(det, ro, rate=rate, ipc_kernel=kernel, gain=2.0,
                        noise_params=noise.NoiseParams(), rng=3,
                        options=EngineOptions(threads=1), **kw)


#: GENERAL with 10-digit values: a 129-character IPCKERN, written as CONTINUE cards
LONG = GENERAL + np.linspace(1e-4, 9e-4, 9).reshape(3, 3) / 3.0
LONG /= LONG.sum()


@pytest.mark.parametrize("kernel", [ipc_kernel(ALPHA), ipc_kernel(0.011, 0.0017),
                                    GENERAL, LONG],
                         ids=["alpha", "diagonal", "asymmetric", "long"])
def test_header_records_the_ipc_kernel(tmp_path, kernel):
    # written with 10 significant digits: round-trips to 1e-10 relative (the long
    # card goes to the exposure and to the slope file without a warning, which
    # pytest would turn into an error)
    path = str(tmp_path / "e.fits")
    write_exposure(_small_engine(kernel), path)
    _, hdr, _ = read_exposure(path)
    assert hdr["IPC"] is True
    k = header_ipc_kernel(hdr)
    np.testing.assert_allclose(k, kernel, rtol=1e-9, atol=1e-12)
    assert k.sum() == pytest.approx(1.0, abs=1e-15)
    mem = write_exposure(_small_engine(kernel), None)["exposure"]
    np.testing.assert_array_equal(header_ipc_kernel(mem.header), k)
    fit_exposure_file(path, str(tmp_path / "f.fits"),
                      options=PrepareOptions(measure_noise=False,
                                             remove_common_mode=False))
    with fits.open(tmp_path / "f.fits") as hdul:
        assert hdul[0].header["IPCDECON"] is True
        np.testing.assert_array_equal(header_ipc_kernel(hdul[0].header), k)


def test_header_without_a_usable_kernel():
    hdr = write_exposure(_small_engine(None), None)["exposure"].header
    assert hdr["IPC"] is False and "IPCKERN" not in hdr
    assert header_ipc_kernel(hdr) is None
    # written before the card existed: IPC on, kernel unknown
    assert header_ipc_kernel(fits.Header([("IPC", True)])) is None
    # the identity: nothing to undo
    ident = fits.Header([("IPC", True), ("IPCKERN", "0,0,0,0,1,0,0,0,0")])
    assert header_ipc_kernel(ident) is None
    for bad in ("0,0.1,0", "0,0.1,0,0.1,0.6,0.1,0,x,0", "0,-0.1,0,0.1,1,0.1,0,0,0"):
        with pytest.raises(FileFormatError, match="IPCKERN"):
            header_ipc_kernel(fits.Header([("IPC", True), ("IPCKERN", bad)]))


def test_noise_free_slopes_of_cores_and_neighbours_are_exact():
    # 9 stars (cores 1e4-4.5e4 e-/s, the brightest reaching FW mid-ramp), RAPID x 20
    # at 0.18 s, bias 5000 e-, no noise: resultants S = bias + K p(min(q, FW)).
    # Undoing K, then inverting p, then fitting gives every unsaturated core and
    # neighbour its own rate to float32 round-off (values ~8e4 e-, ulp 0.008 e-: a
    # slope error < 0.01 e-/s over 3.6 s), and the flags stop at the core's own
    # full-well read, none grown to the neighbours.  Without undoing K the
    # neighbours of the saturated cores miss K * rate by more than 1 e-/s.
    t_frame, nres = 0.18, 20
    times = [np.array([(k + 1) * t_frame]) for k in range(nres)]
    tbar = np.array([t[0] for t in times])
    centres = [(6 + 9 * i, 6 + 9 * j) for i in range(3) for j in range(3)]
    core = np.linspace(1e4, 4.5e4, 9)
    rate = star((30, 30), centres, core)
    k = ipc_kernel(ALPHA)
    m = ipc_matrix(k, 30, 30)
    q = np.minimum(rate[None] * tbar[:, None, None], FW)
    s = 5000.0 + (m @ p(q).reshape(nres, -1).T).T.reshape(q.shape)
    e = s[None].astype(np.float32)                   # (1, nres, 30, 30)
    nl = Nonlinearity((C2, C3))
    first_full = np.where((rate * tbar[-1] >= FW), np.argmax(
        rate[None] * tbar[:, None, None] >= FW, axis=0), -1)
    assert np.sum(first_full >= 0) >= 2               # some cores saturate
    d = undo_ipc(e, k, tolerance=1e-4)
    sat = saturation_flags(d, tbar, SaturationOptions(FW, 1e9, nonlinearity=nl))
    first = np.where(sat[0].any(axis=0), sat[0].argmax(axis=0), -1)
    # the level test (97 % of p(FW)) may flag the read before the full one; no
    # other pixel is flagged
    full = first_full >= 0
    early = first_full[full] - first[full]
    assert np.all((early == 0) | (early == 1))
    assert np.all(first[~full] < 0)
    lin = linearize_resultants(d, nl, tbar)
    fit = fit_ramps(lin, times, read_noise=1.0, saturated=sat)
    ys, xs = core_and_neighbours(centres)
    np.testing.assert_allclose(fit.slope[ys, xs], rate[ys, xs], atol=0.01)
    # control: linearising the IPC-mixed signal (the former path, no flags grown
    # here) against K * rate
    raw = linearize_resultants(e, nl, tbar)
    old = fit_ramps(raw, times, read_noise=1.0, saturated=sat)
    k_rate = (m @ rate.reshape(-1)).reshape(rate.shape)
    nb = np.ones_like(full)
    for y, x in zip(*np.nonzero(full)):
        nb[y - 1:y + 2, x - 1:x + 2] = False
    nb = ~nb & ~full
    assert np.max(np.abs(old.slope[nb] - k_rate[nb])) > 1.0


def _star_engine(kernel, seed, *, nints=4):
    """64 x 64 H2RG (4-pixel reference border), RAPID x 20, 36 stars on 2 e-/s:
    cores from 0.55 to 1.1 x the rate ``f`` that fills FW at read 10 (so all but
    the faintest saturate part-way; nearest neighbours reach at most 0.44 f x 20.5
    frames = 0.86 FW), IPC, nonlinearity, white read noise 8 e- plus kTC and the
    bias pattern (no 1/f)."""
    det = preset("H2RG", naxis1=64, naxis2=64)
    ro = Readout.multiaccum(1, 20, nints=nints, name="RAPID")
    centres = [(9 + 9 * i, 9 + 9 * j) for i in range(6) for j in range(6)]
    f_fill = FW / (10.5 * det.frame_time)
    core = np.linspace(0.55, 1.1, 36) * f_fill
    rate = star(det.shape, centres, core)
    params = noise.NoiseParams(rd_noise=8.0, c_pink=0.0, u_pink=0.0, acn=0.0,
                               pca0=0.0, pedestal=0.0)
    eng = ChargeEngine(det, ro, rate=rate, full_well=FW,
                       nonlinearity=Nonlinearity((C2, C3)), ipc_kernel=kernel,
                       gain=2.0, noise_params=params, rng=seed,
                       options=EngineOptions(threads=1))
    return eng, centres


def test_noisy_core_and_neighbour_slopes_are_unbiased(tmp_path):
    # The engine's exposure, fitted by fit_exposure_file (GLS, IPC undone): for the
    # 36 cores (half of them saturating part-way) and their 144 nearest neighbours
    # over 4 integrations, z = (slope - rate) / sqrt(reported variance) against the
    # input rate map (what a fit of IPC-free ramps recovers; no flat).  Unbiased:
    # |mean z| < 5 / sqrt(n) (5 sigma of the mean of n unit-variance z), n = 180
    # pixels (the integrations are combined in each slope).  The variance is right:
    # |mean z^2 - 1| < 5 sqrt(2 / n).  Measured: mean z = -0.10 (bound 0.37); with
    # deconvolve_ipc=False (the former path, flags grown) against K * rate, -0.97
    # (cores -1.37, neighbours -0.88).
    eng, centres = _star_engine(ipc_kernel(ALPHA), 77)
    rate = eng.expected_rate()
    out = write_exposure(eng, None)
    fit = fit_exposure_file(out["exposure"], str(tmp_path / "f.fits"),
                            jump_threshold=None)
    ys, xs = core_and_neighbours(centres)
    sigma = np.sqrt(fit.var_read + fit.var_poisson)
    z = (fit.slope[ys, xs] - rate[ys, xs]) / sigma[ys, xs]
    n = z.size
    assert abs(z.mean()) < 5 / np.sqrt(n)
    assert abs(np.mean(z ** 2) - 1) < 5 * np.sqrt(2 / n)
    # exactly the pixels whose charge reaches FW (the engine's record) are flagged:
    # 32 cores, no neighbour (no growth once IPC is undone)
    sat = (fit.dq & SATURATED) != 0
    full = (out["sat_read"] >= 0).any(axis=0)
    cy, cx = np.array(centres).T
    assert full[cy, cx].sum() >= 30 and full.sum() == full[cy, cx].sum()
    np.testing.assert_array_equal(sat, full)
    with fits.open(tmp_path / "f.fits") as hdul:
        hdr = hdul[0].header
        assert hdr["IPCDECON"] is True and hdr["LINCORR"] is True
        assert hdr["IPCRNFAC"] == pytest.approx(ipc_noise_gain(ipc_kernel(ALPHA)))
        np.testing.assert_allclose(header_ipc_kernel(hdr), ipc_kernel(ALPHA))


def test_model_read_noise_includes_the_deconvolution_gain():
    # Background pixels (2 e-/s: read-noise dominated) fitted with the model read
    # noise (measure_noise=False): undoing IPC amplifies the 8 e- white read noise
    # by g = 1.065, and the model must say so, else chi2/dof = g^2 = 1.13 (measured
    # 1.139 with the header's 8 e-, 1.004 with the model).  The mean chi2/dof of N
    # pixels with nu dof each (4 integrations x 19 differences - 1 slope = 75) has
    # sd sqrt(2 / nu) / sqrt(N): 0.003 for N = 2812; allowed 5 of it.
    eng, centres = _star_engine(ipc_kernel(ALPHA), 5)
    mem = write_exposure(eng, None)["exposure"]
    prep = prepare_exposure(mem,
                            options=PrepareOptions(refpix="none",
                                                   remove_common_mode=False,
                                                   measure_noise=False))
    g = ipc_noise_gain(ipc_kernel(ALPHA))
    assert prep.read_noise == pytest.approx(float(mem.header["RDNOISE"]) * g)
    assert dict((c[0], c[1]) for c in prep.cards)["IPCRNFAC"] == pytest.approx(g)
    fit = fit_ramps(prep.electrons, prep.read_times, read_noise=prep.read_noise,
                    saturated=prep.saturated, refmask=prep.refmask)
    bg = ~prep.refmask & (eng.expected_rate() < 3.0)
    n, nu = bg.sum(), fit.dof[bg]
    assert n > 2500 and np.all(nu == 75)
    assert abs(fit.chi2[bg].mean() - 1) < 5 * np.sqrt(2 / 75) / np.sqrt(n)


def test_opting_out_leaves_the_ramps_as_they_were():
    # deconvolve_ipc=False (and no linearisation): the electrons are DN x gain
    # untouched, the cards say
    # so, and the saturated pixels' 3 x 3 neighbours are flagged (the kernel is not
    # undone, so their bend is hidden instead)
    eng, centres = _star_engine(ipc_kernel(ALPHA), 9, nints=1)
    mem = write_exposure(eng, None)["exposure"]
    off = prepare_exposure(mem,
                           options=PrepareOptions(refpix="none",
                                                  remove_common_mode=False,
                                                  measure_noise=False, linearize=False,
                                                  deconvolve_ipc=False))
    np.testing.assert_array_equal(off.electrons,
                                  mem.sci.astype(np.float32) * np.float32(2.0))
    cards = dict((c[0], c[1]) for c in off.cards)
    assert cards["IPCDECON"] is False and cards["IPCRNFAC"] == 1.0
    on = prepare_exposure(mem,
                          options=PrepareOptions(refpix="none",
                                                 remove_common_mode=False,
                                                 measure_noise=False))
    assert dict((c[0], c[1]) for c in on.cards)["IPCDECON"] is True
    cy, cx = np.array(centres).T
    core_sat = on.saturated[0, -1, cy, cx]
    assert core_sat.sum() >= 10
    y, x = cy[core_sat][0], cx[core_sat][0]
    assert off.saturated[0, -1, y - 1:y + 2, x - 1:x + 2].all()
    assert not on.saturated[0, -1, y, x + 1] and not on.saturated[0, -1, y + 1, x]
    with pytest.raises(ParameterError, match="deconvolve_ipc"):
        prepare_exposure(mem, options=PrepareOptions(deconvolve_ipc="yes"))


@pytest.mark.parametrize("ramp", [True, False])       # streamed from the file / in memory
def test_a_clipped_star_beside_the_reference_columns_biases_no_row(tmp_path, ramp):
    """A 3e6 e-/s star on the first active column, clipped at the ADC top (no full
    well), with IPC: undoing the kernel spread its clipped value's error into the
    reference column beside it, and the 'jwst' side correction subtracted that from
    whole rows (-170 to -190 e-/s on rows 26-34, found by a hostile probe).  Reference
    pixels within reach of a saturated pixel are now left out of the correction.

    Tolerance: the far rows' scatter of ``slope - rate`` per pixel, s, gives the mean
    of the 9 x 40 pixels beside the star a standard error s / sqrt(360) (white noise
    only, so the pixels are independent up to the side mean's shared noise, which
    the same comparison on a far band of rows includes); the two band means differ by
    less than 5 sqrt(2) of it."""
    from scenesim.io.exposure import read_truth
    from scenesim.io.fitfile import read_fit
    from scenesim.run import run_scene
    from scenesim.scene import parse_scene
    scene = parse_scene({
        "seed": 5, "detector": {"preset": "H2RG", "naxis1": 64, "naxis2": 64},
        "noise": {"preset": "nirspec", "c_pink": 0.0, "u_pink": 0.0, "acn": 0.0,
                  "pca0": 0.0, "pedestal": 0.0},
        "readout": {"pattern": "RAPID", "ngroups": 10},
        "sources": {"background": 200.0, "stars": [{"x": 4.0, "y": 30.0, "flux": 3e6}],
                    "psf": {"kind": "gaussian", "fwhm": 1.5}},
        "effects": {"ipc_alpha": 0.02},
        "output": {"path": str(tmp_path / "s.fits"), "fit": "ols", "refpix": "jwst",
                   "ramp": ramp}})
    res = run_scene(scene, progress=False)
    d = read_fit(res.fit).slope - read_truth(res.truth)["RATE"]
    near = d[26:35, 20:60]
    far = np.concatenate([d[6:15, 20:60].ravel(), d[45:54, 20:60].ravel()])
    se = far.std() / np.sqrt(near.size)
    assert abs(near.mean() - far[:near.size].mean()) < 5 * np.sqrt(2) * se, \
        (near.mean(), far.mean(), se)
