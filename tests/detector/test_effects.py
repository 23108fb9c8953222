"""Tests of the detector effects against closed forms: saturation, nonlinearity, IPC, flat."""

import math
import pickle

import numpy as np
import pytest
from scipy.signal import convolve2d

from noise.errors import ParameterError
from scenesim.detector.nonlinearity import Nonlinearity
from scenesim.detector.flat import apply_flat
from scenesim.detector.ipc import apply_ipc, ipc_kernel
from scenesim.detector.saturation import apply_saturation


# ------------------------------------------------------------------------ saturation
def test_saturation_flags_exact_integer_charge():
    charge = np.array([[0, 99_999, 100_000, 100_001, 5_000_000]], dtype=np.int64)
    clipped, sat = apply_saturation(charge, 1e5)
    assert clipped.dtype == np.int64
    np.testing.assert_array_equal(clipped, [[0, 99_999, 100_000, 100_000, 100_000]])
    np.testing.assert_array_equal(sat, [[False, False, True, True, True]])
    # The input is not modified.
    assert charge[0, 3] == 100_001


def test_saturation_integer_charge_floors_fractional_full_well():
    # A pixel holds whole electrons: a full well of 10.7 e- is 10 e-.
    charge = np.array([[9, 10, 11]], dtype=np.int64)
    clipped, sat = apply_saturation(charge, 10.7)
    np.testing.assert_array_equal(clipped, [[9, 10, 10]])
    np.testing.assert_array_equal(sat, [[False, True, True]])


def test_saturation_map_with_leading_axes():
    fw = np.array([[10.0, 20.0], [30.0, 40.0]])
    reads = np.array([[[5, 25], [30, 39]],
                      [[10, 19], [31, 41]]], dtype=np.int32)   # (2 reads, 2, 2)
    clipped, sat = apply_saturation(reads, fw)
    assert clipped.shape == reads.shape and clipped.dtype == np.int32
    np.testing.assert_array_equal(clipped, [[[5, 20], [30, 39]], [[10, 19], [30, 40]]])
    np.testing.assert_array_equal(sat, [[[False, True], [True, False]],
                                        [[True, False], [True, True]]])


def test_saturation_float_charge_and_null_limit():
    q = np.array([[1.5, 2.5], [3.25, 4.0]])
    clipped, sat = apply_saturation(q, 3.25)
    np.testing.assert_array_equal(clipped, [[1.5, 2.5], [3.25, 3.25]])
    np.testing.assert_array_equal(sat, [[False, False], [True, True]])
    # A full well above every charge changes nothing and flags nothing.
    clipped, sat = apply_saturation(q, 1e9)
    np.testing.assert_array_equal(clipped, q)
    assert not sat.any()


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf, np.ones((3, 3)),
                                 np.array([[1.0, -1.0]]), "1e5", True])
def test_saturation_rejects_bad_full_well(bad):
    with pytest.raises(ParameterError, match="full_well"):
        apply_saturation(np.zeros((1, 2), dtype=np.int64), bad)


# ---------------------------------------------------------------------- nonlinearity
def test_nonlinearity_apply_matches_polynomial():
    c2, c3, c4 = -8e-7, -2e-12, 3e-18
    q = np.array([0.0, 1.0, 1e3, 5e4, 8e4])
    expected = q + c2 * q**2 + c3 * q**3 + c4 * q**4
    np.testing.assert_allclose(Nonlinearity((c2, c3, c4)).apply(q), expected,
                               rtol=1e-15, atol=0)


def test_nonlinearity_quadratic_inverse_matches_closed_form():
    # m = q + c2 q^2  =>  q = 2 m / (1 + sqrt(1 + 4 c2 m))  (the cancellation-free root)
    c2 = -1e-6
    nl = Nonlinearity((c2,))
    assert nl.q_hi == pytest.approx(-1 / (2 * c2), rel=1e-12)
    m = np.linspace(-5e4, nl.measured_range[1] * 0.999, 2001)
    q_closed = 2 * m / (1 + np.sqrt(1 + 4 * c2 * m))
    np.testing.assert_allclose(nl.invert(m), q_closed, rtol=1e-12, atol=1e-9)


def test_nonlinearity_round_trip_over_monotonic_range():
    c2, c3 = -8e-7, -2e-12
    nl = Nonlinearity((c2, c3))
    # p'(q) = 1 + 2 c2 q + 3 c3 q^2 = 0  =>  q = (-2 c2 +- sqrt(4 c2^2 - 12 c3)) / (6 c3)
    disc = math.sqrt(4 * c2**2 - 12 * c3)
    roots = sorted([(-2 * c2 + disc) / (6 * c3), (-2 * c2 - disc) / (6 * c3)])
    assert nl.q_lo == pytest.approx(roots[0], rel=1e-10)
    assert nl.q_hi == pytest.approx(roots[1], rel=1e-10)
    # Up to 0.999 of the turnover: there p' ~ |p''(q_hi)| * 0.001 q_hi = 1.5e-3, so the
    # round-off of the inverse, ~eps / p', stays near 1e-13, far below 1e-9.
    q = np.concatenate([np.linspace(0.0, 0.999 * nl.q_hi, 3999),
                        np.geomspace(1e-3, 1e3, 60),
                        -np.linspace(1.0, 0.999 * -nl.q_lo, 99)]).reshape(-1, 3)
    back = nl.invert(nl.apply(q))
    assert back.shape == q.shape
    np.testing.assert_allclose(back, q, rtol=1e-9, atol=1e-12)
    # And the other way round: p(p^-1(m)) = m.
    m = np.linspace(*nl.measured_range, 1001)[1:-1]
    np.testing.assert_allclose(nl.apply(nl.invert(m)), m, rtol=1e-12, atol=1e-9)


def test_nonlinearity_everywhere_monotonic_inverts_large_values():
    # 4 c2^2 - 12 c3 < 0: p' has no real root, the domain is the whole line.
    nl = Nonlinearity((1e-6, 1e-12))
    assert nl.q_lo == -math.inf and nl.q_hi == math.inf
    q = np.array([-3e7, -1e6, -1.0, 0.0, 2.5, 1e6, 3e7])
    np.testing.assert_allclose(nl.invert(nl.apply(q)), q, rtol=1e-12, atol=1e-12)
    nl.check_monotonic(1e12)


def test_nonlinearity_check_monotonic():
    nl = Nonlinearity((-1e-5,))          # turns over at q = 1 / (2e-5) = 5e4 e-
    nl.check_monotonic(4.99e4)
    with pytest.raises(ParameterError, match="not monotonic up to 50000"):
        nl.check_monotonic(5e4)
    with pytest.raises(ParameterError, match="turns over at 50000"):
        nl.check_monotonic(1e5)
    with pytest.raises(ParameterError, match="max_charge"):
        nl.check_monotonic(-1.0)


def test_nonlinearity_invert_outside_domain_raises():
    nl = Nonlinearity((-1e-5,))          # p(q_hi) = 5e4 - 1e-5 * 2.5e9 = 2.5e4
    assert nl.measured_range[1] == pytest.approx(2.5e4, rel=1e-12)
    with pytest.raises(ParameterError, match="invertible only on"):
        nl.invert([1e3, 2.6e4])
    with pytest.raises(ParameterError, match="finite"):
        nl.invert([np.nan])


def test_nonlinearity_null_limit_and_value_semantics():
    lin = Nonlinearity(())
    assert lin.is_linear and Nonlinearity((0.0, 0.0)) == lin
    q = np.array([[0.0, 3.0], [7.5, 1e5]])
    np.testing.assert_array_equal(lin.apply(q), q)
    np.testing.assert_array_equal(lin.invert(q), q)
    nl = Nonlinearity([-1e-6, 0.0])
    assert nl.coeffs == (-1e-6,) and hash(nl) == hash(Nonlinearity((-1e-6,)))
    assert pickle.loads(pickle.dumps(nl)) == nl
    with pytest.raises(ParameterError, match="finite"):
        Nonlinearity((np.inf,))
    with pytest.raises(ParameterError, match="real numbers"):
        Nonlinearity(("a",))


# ------------------------------------------------------------------------------- IPC
def test_ipc_kernel_values():
    k = ipc_kernel(0.02, 0.003)
    np.testing.assert_array_equal(k, [[0.003, 0.02, 0.003],
                                      [0.02, 1 - 0.08 - 0.012, 0.02],
                                      [0.003, 0.02, 0.003]])
    assert k.sum() == pytest.approx(1.0, abs=1e-15)
    with pytest.raises(ParameterError, match="ipc_alpha"):
        ipc_kernel(-0.01)
    with pytest.raises(ParameterError, match="0.25"):
        ipc_kernel(0.2, 0.1)


def test_ipc_point_source_interior():
    alpha, ad = 0.02, 0.004
    img = np.zeros((7, 9))
    img[3, 4] = 1000.0
    out = apply_ipc(img, ipc_kernel(alpha, ad))
    assert out[3, 4] == pytest.approx(1000 * (1 - 4 * alpha - 4 * ad), rel=1e-15)
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        assert out[3 + dy, 4 + dx] == pytest.approx(1000 * alpha, rel=1e-15)
    for dy, dx in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
        assert out[3 + dy, 4 + dx] == pytest.approx(1000 * ad, rel=1e-15)
    # Nothing beyond the 3x3 neighbourhood.
    mask = np.ones_like(out, dtype=bool)
    mask[2:5, 3:6] = False
    assert np.all(out[mask] == 0)


def test_ipc_edges_keep_outgoing_charge():
    alpha, ad = 0.02, 0.004
    img = np.zeros((5, 6), dtype=np.int64)
    img[0, 0] = 1000      # corner: 2 nearest and 1 diagonal neighbour on the array
    img[4, 3] = 1000      # top edge (last row): 3 nearest and 2 diagonal neighbours
    out = apply_ipc(img, ipc_kernel(alpha, ad))
    assert out.dtype == np.float64
    assert out[0, 0] == pytest.approx(1000 * (1 - 2 * alpha - ad), rel=1e-14)
    assert out[0, 1] == pytest.approx(1000 * alpha) and out[1, 0] == pytest.approx(
        1000 * alpha)
    assert out[1, 1] == pytest.approx(1000 * ad)
    assert out[4, 3] == pytest.approx(1000 * (1 - 3 * alpha - 2 * ad), rel=1e-14)
    assert out.sum() == pytest.approx(2000.0, rel=1e-15)


def test_ipc_conserves_charge_on_random_cubes():
    rng = np.random.default_rng(2024)
    k = rng.uniform(0, 1, (3, 3))
    k /= k.sum()                                  # asymmetric kernel, sum 1
    for shape in [(4, 1, 1), (3, 1, 7), (3, 6, 1), (2, 2, 2), (5, 17, 23)]:
        img = rng.poisson(1000.0, size=shape).astype(np.float64)
        out = apply_ipc(img, k)
        # Each output value is a sum of <= 9 positive terms: relative round-off of a
        # total over n pixels is below n * 9 * eps; 1e-12 is far above that.
        np.testing.assert_allclose(out.sum(axis=(-2, -1)), img.sum(axis=(-2, -1)),
                                   rtol=1e-12)


def test_ipc_matches_convolution_in_interior():
    # Independent implementation: scipy's 2-D convolution, away from the edges.
    rng = np.random.default_rng(7)
    k = rng.uniform(0, 1, (3, 3))
    k /= k.sum()
    img = rng.normal(100.0, 10.0, (12, 15))
    ref = convolve2d(img, k, mode="same")
    out = apply_ipc(img, k)
    np.testing.assert_allclose(out[1:-1, 1:-1], ref[1:-1, 1:-1], rtol=1e-13)


def test_ipc_orientation_and_dtypes():
    # kernel[1 + dy, 1 + dx] is the fraction sent to the pixel at offset (dy, dx).
    k = np.zeros((3, 3))
    k[1, 1], k[1, 2] = 0.9, 0.1                   # only to the right (+x)
    img = np.zeros((3, 4), dtype=np.float32)
    img[1, 1] = 10.0
    out = apply_ipc(img, k)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out[1], [0.0, 9.0, 1.0, 0.0], rtol=1e-6)


def test_ipc_null_limit():
    img = np.random.default_rng(3).poisson(50.0, (2, 6, 5))
    np.testing.assert_array_equal(apply_ipc(img, ipc_kernel(0.0)), img)


@pytest.mark.parametrize("kernel, match", [
    (np.ones((2, 2)) / 4, "3x3"),
    (np.full((3, 3), 1.001 / 9), "sum to 1"),
    (np.array([[0, 0.1, 0], [0.1, 0.9, 0.1], [0, -0.2, 0]]), ">= 0"),
    (np.array([[0, 0, 0], [0, np.nan, 0], [0, 0, 0]]), "finite"),
    (np.full((3, 3), 0.1), "sum to 1"),
])
def test_ipc_rejects_bad_kernels(kernel, match):
    with pytest.raises(ParameterError, match=match):
        apply_ipc(np.ones((4, 4)), kernel)


# ------------------------------------------------------------------------------ flat
def test_apply_flat_scalar_and_map():
    rate = np.arange(12.0).reshape(3, 2, 2)
    flat = np.array([[1.0, 0.5], [0.0, 2.0]])
    np.testing.assert_array_equal(apply_flat(rate, flat), rate * flat[None])
    np.testing.assert_array_equal(apply_flat(rate, 1.0), rate)
    with pytest.raises(ParameterError, match="flat"):
        apply_flat(rate, -0.1)
    with pytest.raises(ParameterError, match=r"\(2, 2\)"):
        apply_flat(rate, np.ones((2, 3)))
    with pytest.raises(ParameterError, match="flat"):
        apply_flat(rate, np.array([[1.0, np.nan], [1.0, 1.0]]))
