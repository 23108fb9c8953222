"""Tridiagonal solves for every pixel at once, and the row chunks they run on.

Every fitter of :mod:`scenesim.rampfit` is a weighted mean of the rate estimates
``d_i`` with weights ``W^-1 1 / (1^T W^-1 1)`` for a tridiagonal "weighting" matrix
``W`` (the model covariance ``C`` for GLS; see :mod:`scenesim.rampfit.fitter`).
:func:`ldl_pass` factors ``W = L D L^T`` (the Thomas recursion) with a loop over the
resultant differences only, vectorised over pixels, in float32.  The same forward
pass accumulates ``1^T W^-1 1``, ``1^T W^-1 y`` and ``y^T W^-1 y`` (``y = d - f_ref``
with ``f_ref`` a reference rate, e.g. the previous estimate, so that the
chi-square does not suffer from cancellation), and an optional back substitution
gives ``x = W^-1 1``, from which the weights follow.  Unusable differences are
removed by replacing their row and column of ``W`` by the identity, which makes
``W`` block diagonal, one block per usable segment, without any grouping of pixels.

:func:`quad_form` evaluates ``x^T M x`` for a tridiagonal ``M`` (the read or the
Poisson part of ``C``), which propagates the weights through the model covariance.

Chunks: per-pixel work arrays are processed in row chunks of about
:data:`CHUNK_PIXELS` pixels whatever the ramp length (:func:`chunk_pixels`,
:func:`row_chunks`), fewer only where a (nints, nres, pixels) array would exceed
:data:`CHUNK_VALUES` values.  The loops over the differences make ~25 numpy calls
per difference, each over one (pixels,) vector: a chunk of a fixed number of
pixels keeps the cost of a call per pixel the same at every ramp length, so the
fit is linear in the number of resultants (a chunk of a fixed number of *values*,
as before, gave 5 x 512 pixels at 200 resultants: numpy's per-call overhead then
grew the cost per difference, time ~ nres^1.3).  16384 pixels is where a call's
overhead (~1 us) is small against its loop and its (pixels,) vectors (64 kB) still
sit in the 2 MB per-core L2 cache (measured: 512^2 x 200, one thread, 1.31 s at
16384 pixels against 1.77 s at 4096 and 1.69 s at 65536).  numpy releases the GIL
in its loops, so chunks run in parallel on a thread pool.  No pixel's result
depends on the chunking.
"""

import numpy as np

__all__ = ["CHUNK_ELEMS", "CHUNK_PIXELS", "CHUNK_VALUES", "TINY", "chunk_pixels",
           "ldl_pass", "quad_form", "row_chunks"]

#: Target number of float32 values per chunk array of the pixel-only steps (the
#: neighbourhood sorts of :mod:`scenesim.rampfit.local_rate`).
CHUNK_ELEMS = 1 << 19

#: Pixels per chunk of the ramp solves, whatever the ramp length (module notes).
CHUNK_PIXELS = 1 << 14

#: At most this many values per (nints, nres, pixels) chunk array: ramps longer
#: than 256 resultants get fewer pixels per chunk, so that a chunk's work arrays
#: stay bounded (~30 bytes per value over the fit's arrays: ~120 MB per thread).
CHUNK_VALUES = 1 << 22

#: Least pivot or variance used as a divisor (guards exact zeros).
TINY = 1e-30

_F32 = np.float32


def chunk_pixels(values_per_pixel):
    """Pixels per chunk for ``values_per_pixel`` values (nints x nres) per pixel:
    :data:`CHUNK_PIXELS`, fewer where that would exceed :data:`CHUNK_VALUES`."""
    return max(1, min(CHUNK_PIXELS, CHUNK_VALUES // max(1, int(values_per_pixel))))


def row_chunks(ny, nx, values_per_pixel, *, rows=None):
    """``[(y0, y1), ...]`` row ranges covering ``ny`` rows of ``nx`` pixels.

    Each holds ``rows`` rows, or (``rows=None``) about :func:`chunk_pixels`
    pixels (at least one row) for ``values_per_pixel`` values per pixel.
    """
    if rows is None:
        rows = max(1, chunk_pixels(values_per_pixel) // max(1, nx))
    return [(y, min(y + rows, ny)) for y in range(0, ny, rows)]


def ldl_pass(d, valid, mf, mc, fref, s2, f, A, B, *, want_x):
    """Forward L D L^T recursion of a tridiagonal W for every pixel at once.

    Parameters
    ----------
    d : ndarray, shape (nd, P), float32
        Rate estimates.
    valid, mf : ndarray, shape (nd, P), bool and float32
        Usable differences.
    mc : ndarray, shape (nd - 1, P), float32
        Couplings (both neighbours usable).
    fref : ndarray, shape (P,), float32
        Reference rate subtracted from ``d`` (``y = d - fref``).
    s2, f : scalar or ndarray (P,) float32
        Read variance per read and rate in ``W``.
    A : (A_read, A_pois or None)
        Lists of nd diagonal coefficients.
    B : (B_read, B_pois or None) or None
        Lists of nd - 1 off-diagonal coefficients.
    want_x : bool, keyword-only
        Also return ``W^-1 1``.

    Masked rows/columns of W are replaced by the identity (their ``y`` is 0).

    Returns
    -------
    S11, S1y, Syy : ndarray, shape (P,), float32
        ``1^T W^-1 1``, ``1^T W^-1 y``, ``y^T W^-1 y`` over the usable differences.
    x : ndarray, shape (nd, P), float32, or None
        ``W^-1 1`` (zero at masked differences) when ``want_x``.
    """
    nd, npix = d.shape
    ar, ap = A
    S11 = np.zeros(npix, _F32)
    S1y = np.zeros(npix, _F32)
    Syy = np.zeros(npix, _F32)
    if want_x:
        Lo = np.zeros((nd, npix), _F32)
        Z = np.empty((nd, npix), _F32)
    u = v = Dprev = None
    one = _F32(1)
    for i in range(nd):
        a = s2 * ar[i]
        if ap is not None:
            a = a + f * ap[i]
        a = np.where(valid[i], a, one)
        y = d[i] - fref
        y *= mf[i]
        if i == 0 or B is None:
            D = a
            u = mf[i]
            v = y
        else:
            b = s2 * B[0][i - 1]
            if B[1] is not None:
                b = b + f * B[1][i - 1]
            b = b * mc[i - 1]
            ell = b / Dprev
            D = a - ell * b
            u = mf[i] - ell * u
            v = y - ell * v
            if want_x:
                Lo[i] = ell
        invd = one / D
        ud = u * invd
        S11 += u * ud
        S1y += v * ud
        Syy += v * v * invd
        if want_x:
            Z[i] = ud
        Dprev = D
    if not want_x:
        return S11, S1y, Syy, None
    x = Z
    for i in range(nd - 2, -1, -1):
        x[i] -= Lo[i + 1] * x[i + 1]
    return S11, S1y, Syy, x


def quad_form(x, A, B):
    """``x^T M x`` per pixel for the tridiagonal M with diagonal A (nd,), off-diagonal B.

    Computed in the dtype of ``x``.  Where ``M`` has negative off-diagonals (the read
    part of the covariance) the sum cancels: for ``x = C^-1 1`` of a 1000-read,
    read-noise dominated ramp its terms are ~1e5 times the result, beyond float32;
    pass float64 ``x`` there (the GLS fitter avoids it: ``x^T C x = 1^T x``).

    Parameters
    ----------
    x : ndarray, shape (nd, P), float32 or float64
    A : array_like, shape (nd,)
    B : array_like, shape (nd - 1,)

    Returns
    -------
    ndarray, shape (P,), dtype of ``x``
    """
    a = np.asarray(A, x.dtype)[:, None]
    q = (a * x * x).sum(axis=0)
    if x.shape[0] > 1:
        b = np.asarray(B, x.dtype)[:, None]
        q += 2 * (b * x[:-1] * x[1:]).sum(axis=0)
    return q
