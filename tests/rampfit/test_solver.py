"""The tridiagonal solves and the row blocks they run on, against dense linear algebra."""

import numpy as np
import pytest

from ramp_sim import jwst_times, roman_times
from scenesim.rampfit.covariance import RampCovariance
from scenesim.rampfit.solver import (CHUNK_PIXELS, CHUNK_PIXELS_THREADED, CHUNK_VALUES,
                                     chunk_pixels, ldl_pass, row_chunks)


def dense_pass(d, valid, fref, s2, f, A, B):
    """``1^T W^-1 1``, ``1^T W^-1 y``, ``y^T W^-1 y`` and ``W^-1 1`` per pixel in
    float64 with ``np.linalg.solve``; masked rows and columns of W are the
    identity, ``1`` and ``y = d - fref`` are 0 there."""
    nd, npix = d.shape
    out = np.zeros((3, npix))
    xs = np.zeros((nd, npix))
    for p in range(npix):
        s2p = s2 if np.isscalar(s2) else float(s2[p])
        fp = f if np.isscalar(f) else float(f[p])
        m = valid[:, p]
        W = np.eye(nd)
        for i in range(nd):
            if m[i]:
                W[i, i] = s2p * A[0][i] + (fp * A[1][i] if A[1] is not None else 0)
            if B is not None and i and m[i] and m[i - 1]:
                W[i, i - 1] = W[i - 1, i] = s2p * B[0][i - 1] + (
                    fp * B[1][i - 1] if B[1] is not None else 0)
        one = m.astype(float)
        y = (d[:, p].astype(float) - float(fref[p])) * one
        x = np.linalg.solve(W, one)
        out[:, p] = one @ x, y @ x, y @ np.linalg.solve(W, y)
        xs[:, p] = x
    return out, xs


@pytest.mark.parametrize("times", [jwst_times(12), roman_times()], ids=["rapid", "roman"])
@pytest.mark.parametrize("kind", ["gls-scalar", "gls-map", "ols", "cds"])
def test_ldl_pass_matches_dense_solves(times, kind):
    rng = np.random.default_rng([4, len(times), len(kind)])
    cov = RampCovariance(times)
    nd, npix = len(times) - 1, 200
    d = (5 + 3 * rng.standard_normal((nd, npix))).astype(np.float32)
    valid = rng.random((nd, npix)) < 0.85
    valid[:, :20] = True
    mf = valid.astype(np.float32)
    mc = mf[:-1] * mf[1:]
    fref = rng.normal(5, 0.5, npix).astype(np.float32)
    f = rng.uniform(0, 50, npix).astype(np.float32)
    if kind.startswith("gls"):
        (A, B), s2 = cov.coefficient_lists(), 9.0
        if kind == "gls-map":
            s2 = rng.uniform(1, 30, npix).astype(np.float32)
    elif kind == "ols":
        A = ((2.0 / cov.dt ** 2).tolist(), None)
        B = ((-1.0 / (cov.dt[:-1] * cov.dt[1:])).tolist(), None)
        s2, f = 1.0, 0.0
    else:
        A, B, s2, f = ((1.0 / cov.dt).tolist(), None), None, 1.0, 0.0
    S11, S1y, Syy, x = ldl_pass(d, valid, mf, mc, fref, s2, f, A, B, want_x=True)
    want, xw = dense_pass(d, valid, fref, s2, f, A, B)
    # float32 recursions on well-conditioned systems (condition number < 1e3 here):
    # relative error ~ nd x 6e-8 x condition < 1e-4; 1e-3 of each quantity's scale
    for got, ref in zip((S11, S1y, Syy), want):
        assert np.allclose(got, ref, rtol=1e-3, atol=1e-3 * np.abs(ref).max())
    assert np.allclose(x, xw, rtol=1e-3, atol=1e-3 * np.abs(xw).max())
    assert np.all(x[~valid] == 0)
    # without the back substitution: the same sums, bit for bit
    again = ldl_pass(d, valid, mf, mc, fref, s2, f, A, B, want_x=False)
    assert again[3] is None
    for a, b in zip(again[:3], (S11, S1y, Syy)):
        assert a.tobytes() == b.tobytes()


def test_blocks_hold_a_fixed_number_of_pixels_until_the_value_cap():
    assert chunk_pixels(5) == chunk_pixels(200) == CHUNK_PIXELS
    assert chunk_pixels(1000) == CHUNK_VALUES // 1000 < CHUNK_PIXELS
    assert row_chunks(10, 4096, 200) == [(y, min(y + 4, 10)) for y in range(0, 10, 4)]
    assert row_chunks(10, 1 << 20, 200) == [(y, y + 1) for y in range(10)]
    assert row_chunks(7, 5, 3, rows=3) == [(0, 3), (3, 6), (6, 7)]


def test_blocks_on_threads_are_longer_but_keep_four_per_thread():
    # on two or more threads: up to CHUNK_PIXELS_THREADED pixels, about four blocks
    # per thread on small arrays, never fewer pixels than on one thread, and the
    # value cap still applies
    assert chunk_pixels(20, threads=1, pixels=4096 ** 2) == CHUNK_PIXELS
    assert chunk_pixels(20, threads=2, pixels=4096 ** 2) == CHUNK_PIXELS_THREADED
    assert chunk_pixels(20, threads=2) == CHUNK_PIXELS_THREADED
    assert chunk_pixels(20, threads=2, pixels=512 ** 2) == 512 ** 2 // 8
    assert chunk_pixels(20, threads=2, pixels=256 ** 2) == CHUNK_PIXELS
    assert chunk_pixels(20, threads=8, pixels=1024 ** 2) == 1024 ** 2 // 32
    assert chunk_pixels(1000, threads=2) == CHUNK_VALUES // 1000
    blocks = row_chunks(2048, 2048, 20, threads=2)
    assert len(blocks) == 2048 * 2048 // CHUNK_PIXELS_THREADED
    assert blocks[0] == (0, CHUNK_PIXELS_THREADED // 2048) and blocks[-1][1] == 2048
