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
in its loops, so chunks run in parallel on a thread pool; there, chunks of up to
:data:`CHUNK_PIXELS_THREADED` pixels keep the threads from queueing for the GIL
between calls (see there).  No pixel's result
depends on the chunking.

What bounds the solves: the number of numpy passes per difference (27 forward, 2 more
with the back substitution), each over one (pixels,) vector in cache, not reading
the data.  :func:`ldl_pass` writes every step into preallocated buffers (``out=``):
the same operations in the same order as with numpy's temporaries, so the same bits,
without allocating ~20 vectors per difference (measured 7-13 % less CPU for a whole
fit, 512 x 512 x 20 and x 200, one thread).
"""

import numpy as np

__all__ = ["CHUNK_ELEMS", "CHUNK_PIXELS", "CHUNK_PIXELS_THREADED", "CHUNK_VALUES", "TINY",
           "chunk_pixels", "ldl_pass", "quad_form", "row_chunks"]

#: Target number of float32 values per chunk array of the pixel-only steps (the
#: neighbourhood sorts of :mod:`scenesim.rampfit.local_rate`).
CHUNK_ELEMS = 1 << 19

#: Pixels per chunk of the ramp solves, whatever the ramp length (module notes).
CHUNK_PIXELS = 1 << 14

#: Pixels per chunk when the chunks run on two or more threads (at most; at least
#: :data:`CHUNK_PIXELS`, and small arrays keep about four chunks per thread).  Each
#: numpy call on a 16384-pixel vector takes ~3 us, and between two calls a thread
#: takes the GIL back: with a second thread doing the same, those hand-offs, not the
#: loops, set the pace, and the second thread bought 0.6-1.05x (BENCHMARKS.md, issue
#: 16).  Four times longer vectors halve the hand-offs per pixel for a few percent
#: of cache locality: the fit on two threads took 0.53-0.61 s instead of 0.69-0.72 s
#: (2048^2 x 20), 0.67-0.71 s instead of 1.04-1.73 s (4096^2 x 5).
CHUNK_PIXELS_THREADED = 1 << 16

#: At most this many values per (nints, nres, pixels) chunk array: ramps longer
#: than 256 resultants get fewer pixels per chunk, so that a chunk's work arrays
#: stay bounded (~30 bytes per value over the fit's arrays: ~120 MB per thread).
CHUNK_VALUES = 1 << 22

#: Least pivot or variance used as a divisor (guards exact zeros).
TINY = 1e-30

_F32 = np.float32


def chunk_pixels(values_per_pixel, *, threads=1, pixels=None):
    """Pixels per chunk for ``values_per_pixel`` values (nints x nres) per pixel:
    :data:`CHUNK_PIXELS` on one thread; on ``threads`` > 1, up to
    :data:`CHUNK_PIXELS_THREADED`, keeping about four chunks per thread of an array
    of ``pixels`` pixels (if given) but never below :data:`CHUNK_PIXELS`; fewer
    where a chunk would exceed :data:`CHUNK_VALUES` values."""
    target = CHUNK_PIXELS
    if threads > 1:
        share = CHUNK_PIXELS_THREADED if pixels is None else int(pixels) // (4 * threads)
        target = max(CHUNK_PIXELS, min(CHUNK_PIXELS_THREADED, share))
    return max(1, min(target, CHUNK_VALUES // max(1, int(values_per_pixel))))


def row_chunks(ny, nx, values_per_pixel, *, rows=None, threads=1):
    """``[(y0, y1), ...]`` row ranges covering ``ny`` rows of ``nx`` pixels.

    Each holds ``rows`` rows, or (``rows=None``) about :func:`chunk_pixels`
    pixels (at least one row) for ``values_per_pixel`` values per pixel, run on
    ``threads`` threads.
    """
    if rows is None:
        per = chunk_pixels(values_per_pixel, threads=threads, pixels=ny * nx)
        rows = max(1, per // max(1, nx))
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
    A : (A_read, A_pois or None[, A_const or None])
        Lists of nd diagonal coefficients: ``W_ii = s2 A_read + f A_pois + A_const``
        (the constant part: white noise added to each resultant once,
        :class:`scenesim.rampfit.covariance.RampCovariance`).
    B : (B_read, B_pois or None[, B_const or None]) or None
        Lists of nd - 1 off-diagonal coefficients, likewise.
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
    ar, ap = A[0], A[1]
    aq = A[2] if len(A) > 2 else None
    bq = B[2] if B is not None and len(B) > 2 else None
    f32 = _F32
    S11 = np.zeros(npix, f32)
    S1y = np.zeros(npix, f32)
    Syy = np.zeros(npix, f32)
    if want_x:
        Lo = np.zeros((nd, npix), f32)
        Z = np.empty((nd, npix), f32)
    # every step writes into these buffers (out=): the same operations in the same
    # order as with numpy's temporaries, to the last bit, without their allocation
    a, b, t, y, Dbuf, ubuf, vbuf, invd, ellbuf, udbuf = (np.empty(npix, f32)
                                                         for _ in range(10))
    masked = ~valid
    scalar_s2 = np.isscalar(s2)
    u = v = Dprev = None
    one = f32(1)
    for i in range(nd):
        if scalar_s2:
            base = s2 * ar[i] if aq is None else s2 * ar[i] + aq[i]
        else:
            base = np.multiply(s2, ar[i], out=a)
            if aq is not None:
                np.add(a, aq[i], out=a)
        if ap is not None:
            np.multiply(f, ap[i], out=t)
            np.add(base, t, out=a)
        elif scalar_s2:
            a.fill(base)
        np.copyto(a, one, where=masked[i])
        np.subtract(d[i], fref, out=y)
        np.multiply(y, mf[i], out=y)
        if i == 0 or B is None:
            np.copyto(Dbuf, a)
            u = mf[i]
            np.copyto(vbuf, y)
        else:
            if scalar_s2:
                bb = s2 * B[0][i - 1] if bq is None else s2 * B[0][i - 1] + bq[i - 1]
            else:
                bb = np.multiply(s2, B[0][i - 1], out=b)
                if bq is not None:
                    np.add(b, bq[i - 1], out=b)
            if B[1] is not None:
                np.multiply(f, B[1][i - 1], out=t)
                np.add(bb, t, out=b)
                np.multiply(b, mc[i - 1], out=b)
            else:
                np.multiply(bb, mc[i - 1], out=b)
            ell = Lo[i] if want_x else ellbuf
            np.divide(b, Dprev, out=ell)
            np.multiply(ell, b, out=t)
            np.subtract(a, t, out=Dbuf)
            np.multiply(ell, u, out=t)
            np.subtract(mf[i], t, out=ubuf)
            u = ubuf
            np.multiply(ell, vbuf, out=t)
            np.subtract(y, t, out=vbuf)
        D = Dbuf
        v = vbuf
        np.divide(one, D, out=invd)
        ud = Z[i] if want_x else udbuf
        np.multiply(u, invd, out=ud)
        np.multiply(u, ud, out=t)
        S11 += t
        np.multiply(v, ud, out=t)
        S1y += t
        np.multiply(v, v, out=t)
        np.multiply(t, invd, out=t)
        Syy += t
        Dprev = D
    if not want_x:
        return S11, S1y, Syy, None
    x = Z
    for i in range(nd - 2, -1, -1):
        np.multiply(Lo[i + 1], x[i + 1], out=t)
        x[i] -= t
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
