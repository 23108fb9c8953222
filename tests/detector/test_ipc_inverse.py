"""Tests of the inverse of IPC, :func:`scenesim.detector.ipc.undo_ipc`, and the white-noise
gain it brings, :func:`scenesim.detector.ipc.ipc_noise_gain`.

References used here, independent of the code under test: ``K`` as a dense matrix
built from the rule of :func:`scenesim.detector.ipc.apply_ipc` (``out[y + dy, x + dx] +=
k[1 + dy, 1 + dx] * x[y, x]``, off-array targets kept) and solved with
``numpy.linalg.solve``; the white-noise gain of ``K^-1`` from its Fourier transform,
``g^2 = mean_k |1 / K(k)|^2``.
"""

import numpy as np
import pytest

from noise.errors import ParameterError
from ipc_theory import ipc_matrix
from scenesim.detector.ipc import ipc_kernel, ipc_noise_gain, undo_ipc


ALPHA = 0.015
#: An asymmetric kernel with diagonal terms (sums to 1)
GENERAL = np.array([[0.002, 0.012, 0.003],
                    [0.020, 0.944, 0.010],
                    [0.001, 0.006, 0.002]])


@pytest.mark.parametrize("kernel",
                         [ipc_kernel(ALPHA), ipc_kernel(0.02, 0.004), GENERAL],
                         ids=["alpha", "diagonal", "asymmetric"])
def test_undo_ipc_is_the_inverse_of_the_dense_operator(kernel):
    # A 9 x 11 image with a 1e5 contrast (bright pixels on the edges and corners,
    # where the kept charge makes the operator differ from a convolution).  The
    # iteration's error bound is the tolerance: checked at 1e-3 and 1e-8 (float64).
    rng = np.random.default_rng(31)
    ny, nx = 9, 11
    x = rng.normal(5000.0, 300.0, (2, ny, nx))
    x[:, 4, 5] += 9e4
    x[:, 0, 3] += 5e4
    x[:, -1, -1] += 7e4
    m = ipc_matrix(kernel, ny, nx)
    s = (m @ x.reshape(2, -1).T).T.reshape(x.shape)
    for tol in (1e-3, 1e-8):
        out = undo_ipc(s, kernel, tolerance=tol)
        assert out.dtype == np.float64 and out.shape == x.shape
        assert np.max(np.abs(out - x)) <= tol
    # float32: the same to float32 round-off of ~1e5 e- values (ulp 0.0078 e-)
    out32 = undo_ipc(s.astype(np.float32), kernel, tolerance=1e-3)
    assert out32.dtype == np.float32
    assert np.max(np.abs(out32 - x)) < 0.05
    # the identity kernel changes nothing
    identity = np.array([[0, 0, 0], [0, 1.0, 0], [0, 0, 0]])
    np.testing.assert_array_equal(undo_ipc(s, identity), s)


def test_row_blocks_do_not_change_the_result():
    # undo_ipc works in row blocks with halos (about 2**18 pixels: 128 rows of this
    # 2048-wide frame) and a row's result depends only on the rows within the
    # iteration count of it (a few here; 40 is far more).  So the interior of a crop
    # whose blocks start elsewhere, and whose range (hence iteration count) is the
    # same, must come out bit for bit as in the whole frame; threads change nothing.
    rng = np.random.default_rng(5)
    s = rng.uniform(8e3, 1.2e4, (2, 300, 2048)).astype(np.float32)
    s[:, 150, 4] = 8e4                                 # the range of every frame...
    s[:, 160, 9] = 5e3                                 # ...inside the crop below
    whole = undo_ipc(s, GENERAL, tolerance=1e-3)
    crop = undo_ipc(s[:, 60:], GENERAL, tolerance=1e-3)  # blocks at rows 60, 188
    np.testing.assert_array_equal(crop[:, 40:200], whole[:, 100:260])  # spans 128, 188
    np.testing.assert_array_equal(undo_ipc(s, GENERAL, tolerance=1e-3, threads=2), whole)
    identity = np.array([[0, 0, 0], [0, 1.0, 0], [0, 0, 0]])
    np.testing.assert_array_equal(undo_ipc(s, identity), s)


@pytest.mark.parametrize("kernel", [ipc_kernel(ALPHA), GENERAL], ids=["alpha", "asym"])
def test_noise_gain_matches_the_fourier_integral(kernel):
    # g^2 = (2 pi)^-2 int |1 / K(w)|^2 d^2w, K(w) = sum_d k_d exp(-i w.d); on a
    # 256 x 256 grid the aliasing error is ~rho^256 (rho = 0.07): exact to round-off.
    n = 256
    w = 2 * np.pi * np.fft.fftfreq(n)
    wy, wx = np.meshgrid(w, w, indexing="ij")
    kw = sum(kernel[1 + dy, 1 + dx] * np.exp(-1j * (wy * dy + wx * dx))
             for dy in (-1, 0, 1) for dx in (-1, 0, 1))
    g = np.sqrt(np.mean(1.0 / np.abs(kw) ** 2))
    assert ipc_noise_gain(kernel) == pytest.approx(g, rel=1e-9)
    assert g > 1.0


@pytest.mark.parametrize("kwargs, match", [
    (dict(kernel=ipc_kernel(0.13)), "centre"),          # 1 - 4a = 0.48: no contraction
    (dict(kernel=np.ones((2, 2)) / 4), "3x3"),
    (dict(kernel=GENERAL * 2), "sum to 1"),
    (dict(tolerance=0.0), "tolerance"),
    (dict(tolerance=float("nan")), "tolerance"),
    (dict(threads=0), "threads"),
    (dict(image=np.zeros(5)), "image"),
    (dict(image=np.full((3, 3), np.nan)), "image"),
])
def test_undo_ipc_rejects_bad_arguments(kwargs, match):
    args = dict(image=np.zeros((4, 4)), kernel=ipc_kernel(ALPHA))
    args.update(kwargs)
    image, kernel = args.pop("image"), args.pop("kernel")
    with pytest.raises(ParameterError, match=match):
        undo_ipc(image, kernel, **args)


# ------------------------------------------------ reference pixels are not coupled
def test_reference_pixels_are_not_coupled():
    # A point charge next to a 2-pixel reference border: by hand, 2 % into each
    # regular nearest neighbour, none into the reference pixel above it, whose
    # share stays in the source (the border is an edge); the reference pixels keep
    # their values (here a reference level of 7), and undo_ipc inverts it.
    from scenesim.detector.ipc import apply_ipc, regular_region
    ref = np.zeros((8, 9), bool)
    ref[:2], ref[-2:], ref[:, :2], ref[:, -2:] = True, True, True, True
    assert regular_region(ref) == (slice(2, 6), slice(2, 7))
    img = np.where(ref, 7.0, 0.0)
    img[2, 4] = 100.0
    k = ipc_kernel(0.02)
    out = apply_ipc(img, k, refmask=ref)
    assert np.all(out[ref] == 7.0)
    assert out[2, 4] == pytest.approx(100 * (1 - 3 * 0.02))
    for y, x in ((3, 4), (2, 3), (2, 5)):
        assert out[y, x] == pytest.approx(2.0)
    assert out[~ref].sum() == pytest.approx(100.0)
    back = undo_ipc(out, k, tolerance=1e-12, refmask=ref)
    np.testing.assert_allclose(back, img, atol=1e-10)
    with pytest.raises(ParameterError, match="'refmask'"):
        apply_ipc(img, k, refmask=ref[:-1])


def test_the_engine_leaves_reference_pixels_without_signal(tmp_path):
    # The probe's case: a 2e4 e-/s star at x = 4.6, beside the 4-pixel reference
    # border, with 2 % IPC and no noise (bias 0): the reference pixels read 0 DN on
    # every read (they read 752 DN before), the truth's RATE_IPC is 0 on them, and
    # it conserves the rate of the regular pixels.
    from astropy.io import fits
    from scenesim.engine import EngineOptions
    from scenesim.run import run_scene
    from scenesim.scene import parse_scene
    scene = parse_scene({
        "seed": 3, "detector": {"preset": "H2RG", "naxis1": 32, "naxis2": 32},
        "noise": {"preset": "none"}, "readout": {"pattern": "RAPID", "ngroups": 4},
        "sources": {"psf": {"kind": "gaussian", "fwhm": 2.0},
                    "stars": [{"x": 4.6, "y": 15.0, "flux": 2e4}]},
        "effects": {"ipc_alpha": 0.02},
        "output": {"path": str(tmp_path / "e.fits"), "truth": True, "fit": ""}})
    run_scene(scene, progress=False, options=EngineOptions(threads=1))
    ref = scene.detector.reference_mask()
    with fits.open(tmp_path / "e.fits") as e, fits.open(tmp_path / "e_truth.fits") as t:
        sci = e["SCI"].data
        rate, rate_ipc = t["RATE"].data, t["RATE_IPC"].data
    assert np.all(sci[..., ref] == 0)
    assert np.all(rate_ipc[ref] == 0)
    assert rate_ipc.sum(dtype=float) == pytest.approx(rate.sum(dtype=float), rel=1e-6)


def test_a_window_of_reference_pixels_only_is_left_as_it_is():
    # no regular pixel: the identity (apply_ipc raised IndexError, and with it a
    # run of such a window with IPC)
    from scenesim.detector.ipc import apply_ipc
    img = np.arange(2 * 32 * 4, dtype=float).reshape(2, 32, 4)
    ref = np.ones((32, 4), bool)
    k = ipc_kernel(0.015)
    np.testing.assert_array_equal(apply_ipc(img, k, refmask=ref), img)
    np.testing.assert_array_equal(undo_ipc(img, k, refmask=ref), img)
