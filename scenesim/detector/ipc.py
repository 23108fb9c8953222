"""Inter-pixel capacitance (IPC), forward (the engine) and inverse (deconvolution).

Capacitive coupling between neighbouring pixel nodes makes a fraction ``alpha`` of each
pixel's signal appear in each of its four nearest neighbours and ``alpha_diag`` in each
diagonal neighbour (Moore, Ninkov & Forrest 2004, Proc. SPIE 5167, 204; Kannawadi et al.
2016, PASP 128, 095001).  The image is convolved with the 3x3 kernel::

    [[ad,  a,  ad],
     [ a, 1-4a-4ad, a],
     [ad,  a,  ad]]

IPC is linear, so applying it to the charge of every read (from reset) is the same as
applying it to every difference of reads.  It acts on the signal, after shot noise, so
it correlates the Poisson noise of neighbours; that is the physical behaviour.  At the
edge of the read-out array the charge that would flow off the array **stays in its own
pixel**, so the total charge is conserved exactly.  (For a subarray this is an
approximation: in the real device charge would couple to unread neighbours.)
Reference pixels have no photodiode and are not coupled: with ``refmask`` the kernel
acts on the regular pixels only (:func:`regular_region`, a rectangle), whose border
with the reference pixels is an edge like the array's, and the reference pixels are
left as they are.  That is how the JWST pipeline's ipc step treats them (their values
unchanged, contributing nothing to their neighbours); before, a star next to the
4-pixel reference border put 752 DN into a reference pixel and contaminated the
reference correction.

Inverse: :func:`undo_ipc` is the exact inverse of :func:`apply_ipc`, edges included,
solved iteratively to a stated tolerance.  White noise added after IPC (read noise)
comes out of the inverse amplified by :func:`ipc_noise_gain`.
"""

import math
import numbers
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from noise.errors import ParameterError, ParameterTypeError
from noise.validate import check_image, describe

__all__ = ['ipc_kernel', 'apply_ipc', 'ipc_keep', 'undo_ipc', 'ipc_noise_gain',
           'check_kernel', 'regular_region']


# -------------------------------------------------------------------------------- IPC
def check_kernel(kernel):
    """``kernel`` as a 3x3 float64 array of finite values >= 0, renormalised to sum
    exactly 1 (it must sum to 1 within 1e-9), or a ParameterError."""
    try:
        k = np.asarray(kernel, dtype=np.float64) \
            if not isinstance(kernel, (str, bytes, dict)) else None
        if k is not None and np.asarray(kernel).dtype.kind not in "iuf":
            k = None                            # booleans or objects are not weights
    except (TypeError, ValueError):
        k = None
    if k is None:
        raise ParameterTypeError(
            f"'ipc_kernel' must be a 3x3 array of numbers, got {describe(kernel)}")
    if k.shape != (3, 3):
        raise ParameterError(f"'ipc_kernel' must be a 3x3 array, got shape {k.shape}")
    if not np.all(np.isfinite(k)) or np.any(k < 0):
        raise ParameterError(
            f"'ipc_kernel' entries must be finite and >= 0, got {k.tolist()!r}")
    total = float(k.sum())
    if abs(total - 1.0) > 1e-9:
        raise ParameterError(
            f"'ipc_kernel' must sum to 1 (charge conservation), got sum {total!r} "
            f"for {k.tolist()!r}")
    return k / total


def ipc_kernel(alpha, alpha_diag=0.0):
    """Symmetric 3x3 IPC kernel.

    Parameters
    ----------
    alpha : float
        Fraction of a pixel's signal seen by each of its 4 nearest neighbours, >= 0.
    alpha_diag : float
        Fraction seen by each of its 4 diagonal neighbours, >= 0.

    Returns
    -------
    ndarray, shape (3, 3), float64
        ``[[ad, a, ad], [a, 1 - 4a - 4ad, a], [ad, a, ad]]``, read-only, summing to 1.

    Raises
    ------
    ParameterError
        If a coupling is negative or not finite, or ``4 alpha + 4 alpha_diag > 1``.
    """
    for name, v in (("ipc_alpha", alpha), ("ipc_alpha_diag", alpha_diag)):
        if isinstance(v, bool) or not isinstance(v, (numbers.Real, np.number)) \
                or not math.isfinite(v) or v < 0:
            raise ParameterError(f"{name!r} must be a finite number >= 0, got {describe(v)}")
    a, ad = float(alpha), float(alpha_diag)
    if 4 * a + 4 * ad > 1:
        raise ParameterError(
            f"'ipc_alpha' + 'ipc_alpha_diag' must be <= 0.25 (the centre keeps "
            f"1 - 4 alpha - 4 alpha_diag >= 0), got {a!r} + {ad!r}")
    k = np.array([[ad, a, ad], [a, 1.0 - 4 * a - 4 * ad, a], [ad, a, ad]])
    k.setflags(write=False)
    return k


def ipc_keep(kernel, ny, nx):
    """Fraction of its own charge each pixel keeps under :func:`apply_ipc`.

    The centre weight plus every offset whose destination is off the array (that charge
    stays in the pixel, which is how :func:`apply_ipc` conserves charge at the edges).

    Parameters
    ----------
    kernel : ndarray, shape (3, 3)
        A checked IPC kernel.
    ny, nx : int
        Image shape.

    Returns
    -------
    ndarray, shape (ny, nx), float64
    """
    k = np.asarray(kernel, dtype=np.float64)
    keep = np.full((ny, nx), k[1, 1])
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            w = k[1 + dy, 1 + dx]
            if (dy, dx) == (0, 0) or w == 0.0:
                continue
            off = np.zeros((ny, nx), dtype=bool)
            if dy:
                off[-1 if dy == 1 else 0, :] = True
            if dx:
                off[:, -1 if dx == 1 else 0] = True
            keep[off] += w
    return keep


def regular_region(refmask):
    """``(rows, cols)`` slices of the regular (non-reference) pixels of a read-out image
    whose reference pixels are ``refmask`` (ny, nx) bool: the rows and columns that
    are not reference pixels throughout (a window's regular pixels are a rectangle);
    empty slices when every pixel is a reference pixel."""
    m = np.asarray(refmask, dtype=bool)
    rows = np.flatnonzero(~m.all(axis=1))
    cols = np.flatnonzero(~m.all(axis=0))
    if rows.size == 0 or cols.size == 0:
        return slice(0, 0), slice(0, 0)
    return slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1)


def _region(refmask, shape):
    """The slices :func:`apply_ipc` and :func:`undo_ipc` act on (all of ``shape`` when
    ``refmask`` is None), or a ParameterError for a mask of another shape."""
    if refmask is None:
        return slice(None), slice(None)
    m = np.asarray(refmask)
    if m.shape != tuple(shape) or m.dtype != bool:
        raise ParameterError(f"'refmask' must be a bool array of the image's shape "
                             f"{tuple(shape)}, got {m.dtype} shape {m.shape}")
    return regular_region(m)


def apply_ipc(image, kernel, *, refmask=None):
    """Convolve the last two axes with a 3x3 IPC kernel, conserving charge.

    ``out[y + dy, x + dx] += kernel[1 + dy, 1 + dx] * image[y, x]`` for the 9 offsets
    ``dy, dx`` in {-1, 0, 1} (a true convolution; identical to correlation for the
    symmetric kernels of :func:`ipc_kernel`).  Charge whose destination lies outside the
    array stays in its source pixel, so ``out.sum() == image.sum()`` to round-off.

    Parameters
    ----------
    image : ndarray, shape (..., ny, nx), int or float, e-
    kernel : array_like, shape (3, 3)
        Finite, >= 0, summing to 1 (within 1e-9; it is then renormalised exactly).
    refmask : ndarray of bool, shape (ny, nx), keyword-only, optional
        Reference pixels: not coupled (module notes); the kernel acts on the
        regular pixels' rectangle only, whose border is an edge.

    Returns
    -------
    ndarray, shape (..., ny, nx), e-
        float64 for integer or float64 input, float32 for float32 input.

    Raises
    ------
    ParameterError
        If the kernel is not 3x3, has negative or non-finite entries, or does not sum
        to 1.
    """
    img = check_image("image", image)
    k = check_kernel(kernel)
    dtype = np.result_type(img.dtype, np.float32)
    img = img.astype(dtype, copy=False)
    ys, xs = _region(refmask, img.shape[-2:])
    if refmask is not None:
        out = img.copy()
        sub = img[..., ys, xs]
        if sub.shape[-1] and sub.shape[-2]:      # else every pixel is a reference one
            out[..., ys, xs] = _convolve(sub, k, dtype)
        return out
    return _convolve(img, k, dtype)


def _convolve(img, k, dtype):
    """:func:`apply_ipc` of the whole of ``img`` (checked, of ``dtype``)."""
    ny, nx = img.shape[-2:]
    keep = ipc_keep(k, ny, nx)
    out = img * keep.astype(dtype)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            w = k[1 + dy, 1 + dx]
            if (dy, dx) == (0, 0) or w == 0.0:
                continue
            src_y = slice(max(0, -dy), ny - max(0, dy))
            dst_y = slice(max(0, dy), ny - max(0, -dy))
            src_x = slice(max(0, -dx), nx - max(0, dx))
            dst_x = slice(max(0, dx), nx - max(0, -dx))
            out[..., dst_y, dst_x] += dtype.type(w) * img[..., src_y, src_x]
    return out


def _kernel_for_deconvolution(kernel):
    """``kernel`` checked (3x3, finite, >= 0, sum 1, centre > 1/2) and renormalised."""
    k = check_kernel(kernel)
    if not k[1, 1] > 0.5:
        raise ParameterError(
            f"'kernel' must keep more than half of the charge in its centre (the "
            f"iteration contracts by (1 - centre) / centre < 1), got centre "
            f"{k[1, 1]!r}; allowed: 4 alpha + 4 alpha_diag < 0.5")
    return k


#: Pixels per row block of the IPC deconvolution (the block and its halo stay in the
#: cache through the iterations: 128 rows of a 2048-wide frame).
_DECONV_BLOCK = 1 << 18


class _Deconvolver:
    """Jacobi iteration that undoes :func:`scenesim.detector.ipc.apply_ipc` on 2-D frames
    (see :func:`undo_ipc`); holds the per-shape constants.

    A frame is done in row blocks of ``h`` rows, each with a halo of ``n`` rows (the
    iteration count) on either side: a step moves information by one row, so after
    ``n`` steps the block's own rows equal those of ``n`` steps on the whole frame,
    and the block's buffers stay in the cache.  The frame is overwritten block after
    block; the ``n`` original rows above the next block are kept aside first.
    """

    def __init__(self, k, ny, nx, dtype):
        self.k, self.ny, self.nx = k, ny, nx
        self.dtype = np.dtype(dtype)
        self.rho = (1.0 - k[1, 1]) / k[1, 1]
        # neighbours grouped by weight: out[p] += w * x[p - d]; in a zero-padded
        # buffer x[p - d] is xp[1 + y - dy, 1 + x - dx] (sources off the array: 0)
        groups = {}
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                w = float(k[1 + dy, 1 + dx])
                if (dy, dx) != (0, 0) and w != 0.0:
                    groups.setdefault(w, []).append((1 - dy, 1 - dx))
        self.groups = [(self.dtype.type(-w / k[1, 1]), offs)
                       for w, offs in groups.items()]
        self.inv_centre = self.dtype.type(1.0 / k[1, 1])
        # border: x = (S - sum) / keep = (S / c - sum / c) * (c / keep)
        keep = ipc_keep(k, ny, nx)
        fac = (k[1, 1] / keep).astype(self.dtype)
        # max |K 1 - 1|, on the border only (0 for a kernel with k[1+d] = k[1-d]; see
        # __call__); K 1 at a pixel depends only on which of its neighbours exist,
        # so a frame of at most 5 x 5 has every value that the full one has
        ones = np.ones((min(ny, 5), min(nx, 5)))
        self.delta = float(np.max(np.abs(apply_ipc(ones, k) - 1.0)))
        self.row_fac = {0: fac[0], ny - 1: fac[ny - 1]}
        self.row_fac = {y: f for y, f in self.row_fac.items() if np.any(f != 1)}
        self.col_fac = [(x, fac[:, x]) for x in sorted({0, nx - 1})
                        if np.any(fac[1:ny - 1, x] != 1)]

    def _step(self, src, dst, scaled, s, m, lo):
        """One step on rows ``lo .. lo + m`` of the frame, from the padded block
        ``src`` into the interior of ``dst``; ``scaled`` is ``S / c``."""
        nx = self.nx
        out = dst[1:m + 1, 1:nx + 1]
        if not self.groups:                      # the identity kernel
            np.copyto(out, scaled[:m])
            return
        for i, (coef, offs) in enumerate(self.groups):
            tgt = out if i == 0 else s[:m]
            views = [src[r:r + m, c:c + nx] for r, c in offs]
            if len(views) > 1:
                np.add(views[0], views[1], out=tgt)
            else:
                np.copyto(tgt, views[0])
            for v in views[2:]:
                tgt += v
            tgt *= coef
            if i:
                out += tgt
        out += scaled[:m]
        for y, f in self.row_fac.items():
            if lo <= y < lo + m:
                out[y - lo] *= f
        for x, f in self.col_fac:
            a, b = max(lo, 1), min(lo + m, self.ny - 1)
            if b > a:
                out[a - lo:b - lo, x] *= f[a:b]

    def __call__(self, frame, tolerance):
        """Deconvolve ``frame`` (ny, nx) in place; return the iterations made."""
        ny, nx = self.ny, self.nx
        # first change |x_1 - x_0| = |S - K S| / keep, keep >= c; S - K S =
        # sum_d k_d (S(p) - S(p - d)) + (1 - (K 1)(p)) S(p), the sum over the
        # neighbours on the array (weights <= 1 - c), so that
        # |x_1 - x_0| <= rho (max S - min S) + |1 - K 1| max|S| / c
        hi, lo = float(np.max(frame)), float(np.min(frame))
        first = self.rho * (hi - lo) + self.delta * max(hi, -lo) / self.k[1, 1]
        n = _iterations(self.rho, first, tolerance)
        h = min(ny, max(n, _DECONV_BLOCK // max(nx, 1), 1))
        rows = min(ny, h + 2 * n)
        a = np.zeros((rows + 2, nx + 2), self.dtype)
        b = np.zeros_like(a)
        s = np.empty((rows, nx), self.dtype)
        scaled = np.empty((rows, nx), self.dtype)
        carry = np.empty((min(n, ny), nx), self.dtype)
        for y0 in range(0, ny, h):
            y1 = min(ny, y0 + h)
            lo, hi = max(0, y0 - n), min(ny, y1 + n)
            m = hi - lo
            above = y0 - lo                      # rows above y0: kept aside before
            x0 = a[1:m + 1, 1:nx + 1]
            if above:
                x0[:above] = carry[carry.shape[0] - above:]
            x0[above:] = frame[y0:hi]
            a[m + 1:] = 0
            b[m + 1:] = 0
            np.multiply(x0, self.inv_centre, out=scaled[:m])
            src, dst = a, b
            for _ in range(n):
                self._step(src, dst, scaled, s, m, lo)
                src, dst = dst, src
            if y1 < ny:                          # original rows above the next block
                keep = min(n, y1)
                carry[carry.shape[0] - keep:] = frame[y1 - keep:y1]
            frame[y0:y1] = src[1 + above:1 + above + (y1 - y0), 1:nx + 1]
        return n


def _iterations(rho, first_change, tolerance):
    """Jacobi iterations n for an error below ``tolerance``: the map contracts by
    ``rho`` in the max norm, so ``|x_n - x*| <= rho^n / (1 - rho) |x_1 - x_0|``."""
    if first_change <= 0 or rho == 0:
        return 1
    n = math.log(tolerance * (1 - rho) / first_change) / math.log(rho)
    return max(1, math.ceil(n))


def _deconvolve_frames(frames, kernel, tolerance, threads=1):
    """Undo IPC on every 2-D frame of ``frames`` (..., ny, nx), float, in place.

    ``kernel`` must already be checked (:func:`_kernel_for_deconvolution`).  Frames
    are independent: with ``threads > 1`` they are shared among worker threads (numpy
    releases the GIL in the array passes).  Returns the largest number of iterations
    made.
    """
    ny, nx = frames.shape[-2:]
    flat = frames.reshape((-1, ny, nx))
    if flat.shape[0] == 0 or ny == 0 or nx == 0:
        return 0
    dec = _Deconvolver(kernel, ny, nx, frames.dtype)
    threads = max(1, min(int(threads), flat.shape[0]))
    if threads == 1:
        n = max(dec(f, tolerance) for f in flat)
    else:
        with ThreadPoolExecutor(threads) as pool:
            n = max(pool.map(lambda f: dec(f, tolerance), flat))
    if not np.shares_memory(flat, frames):          # reshape had to copy
        frames[...] = flat.reshape(frames.shape)
    return n


def undo_ipc(image, kernel, *, tolerance=1e-3, threads=1, out=None, refmask=None):
    """Undo :func:`scenesim.detector.ipc.apply_ipc`: the ``x`` with ``apply_ipc(x, kernel)
    == image`` on the last two axes, edges included.

    Jacobi iteration ``x <- (S - sum_{d != 0} k_d x[. - d]) / keep`` from ``x_0 = S``,
    ``keep`` the fraction a pixel keeps (the centre, plus on the array's border the
    weights whose targets are off the array, which :func:`apply_ipc` leaves in the
    pixel).  The map contracts by ``rho = (1 - centre) / centre`` in the max norm
    (``4 (alpha + alpha_diag) / (1 - 4 alpha - 4 alpha_diag)``: 0.064 for ``alpha =
    1.5 %``), so after ``n`` steps the error is at most ``rho^n / (1 - rho)`` times
    the largest change of the first step (Banach); ``n`` is the least that puts this
    bound below ``tolerance``, for each frame.  The first change, ``|(I - K) S| /
    keep``, is bounded a priori (no extra pass) by ``rho (max S - min S)`` plus, for
    a kernel that is not point-symmetric, ``|1 - K 1| max|S| / centre`` on the
    border: for a frame spanning 7.4e4 e- and a tolerance of 5e-3 e- (1e-3 of a 5
    e- read noise), ``n`` = 6 at ``alpha = 1.5 %`` (each step divides the error by
    15.7).  float32 input is iterated in float32 (round-off ~1e-7 of the values,
    not amplified: the map contracts).  A frame is done in row blocks that stay in
    the cache, each with an ``n``-row halo, which gives the same result as whole
    frames.

    Parameters
    ----------
    image : ndarray, shape (..., ny, nx), float, e- (or any unit)
        Signal after IPC; leading axes (integrations, resultants) are independent
        frames.
    kernel : array_like, shape (3, 3)
        The kernel of :func:`apply_ipc` (finite, >= 0, summing to 1 within 1e-9,
        then renormalised), keeping more than half in its centre (``4 alpha + 4
        alpha_diag < 0.5``; real detectors: a few %).
    tolerance : float, keyword-only
        Largest error allowed (unit of ``image``), > 0.
    threads : int, keyword-only
        Worker threads over the frames, >= 1.
    out : ndarray, keyword-only, optional
        Where to write the result (may be ``image`` itself).
    refmask : ndarray of bool, shape (ny, nx), keyword-only, optional
        Reference pixels, as :func:`apply_ipc` takes them: left as they are.

    Returns
    -------
    ndarray, shape of ``image``
        float32 for float32 input, float64 otherwise (a new array, or ``out``).

    Raises
    ------
    noise.errors.ParameterError
        Bad kernel (including a centre <= 1/2, for which the iteration does not
        converge), tolerance or threads, or ``image`` not at least 2-D.

    Notes
    -----
    Linear, so undoing IPC on a resultant (a mean of reads) gives the mean of the
    reads before IPC.  White noise added after IPC (read noise) comes out amplified by
    ``sqrt(sum_j (K^-1)_j^2)`` (1.065 for ``alpha = 1.5 %``; see
    :func:`ipc_noise_gain`) and anticorrelated between neighbours.  Cost on this
    machine (one thread): 13 ms per step for a 2048 x 2048 float32 frame with a
    nearest-neighbour kernel, 16 ms with diagonal terms, 21 ms for 8 distinct
    weights; two threads over the frames: ~0.6 of that.
    """
    img = np.asarray(image)
    if img.ndim < 2 or img.dtype.kind not in "fiu" or not np.all(np.isfinite(img)):
        raise ParameterError(
            f"'image' must be a finite real array with at least 2 dimensions (..., ny, "
            f"nx), got {img.dtype} shape {img.shape}")
    k = _kernel_for_deconvolution(kernel)
    if isinstance(tolerance, bool) or not isinstance(tolerance, numbers.Real) \
            or not math.isfinite(tolerance) or tolerance <= 0:
        raise ParameterError(
            f"'tolerance' must be a finite number > 0, got {describe(tolerance)}")
    if isinstance(threads, bool) or not isinstance(threads, numbers.Integral) \
            or threads < 1:
        raise ParameterError(f"'threads' must be an integer >= 1, got {describe(threads)}")
    dtype = np.float32 if img.dtype == np.float32 else np.float64
    if out is None:
        out = img.astype(dtype, copy=True)
    elif not isinstance(out, np.ndarray):
        raise ParameterTypeError(
            f"'out' must be a {np.dtype(dtype)} array of shape {img.shape} or None, got "
            f"{describe(out)}")
    elif out.shape != img.shape or out.dtype != dtype:
        raise ParameterError(
            f"'out' must be a {np.dtype(dtype)} array of shape {img.shape}, got "
            f"{out.dtype} shape {out.shape}")
    elif out is not img:
        np.copyto(out, img)
    ys, xs = _region(refmask, img.shape[-2:])
    view = out[..., ys, xs]
    if view.size:                                # else every pixel is a reference one
        _deconvolve_frames(view, k, float(tolerance), int(threads))
    return out


def ipc_noise_gain(kernel):
    """Factor by which undoing IPC amplifies white noise added after it.

    ``sqrt(sum_j (K^-1)_j^2)``, the norm of the inverse kernel, far from the array's
    edges (computed by deconvolving a unit impulse on a 41 x 41 grid: the inverse
    kernel decays by ``rho`` per pixel, so the truncation is ``< rho^20``).  The read
    noise of one read after :func:`undo_ipc` is this times the read noise.

    Parameters
    ----------
    kernel : array_like, shape (3, 3)
        As for :func:`undo_ipc`.

    Returns
    -------
    float
        >= 1; 1.0655 for ``ipc_kernel(0.015)``.
    """
    k = _kernel_for_deconvolution(kernel)
    delta = np.zeros((41, 41))
    delta[20, 20] = 1.0
    _deconvolve_frames(delta, k, 1e-15)
    return float(np.sqrt(np.sum(delta ** 2)))
