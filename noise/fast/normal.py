"""Bulk float32 standard normals: a vectorised Box-Muller transform with exact tails.

Why: standard normals are most of a noise run's cost (DESIGN.md section 7).  numpy's
float32 ziggurat costs 9-11 ns per draw on this machine (more when the other core is
busy) because it branches per sample; a Box-Muller transform vectorises completely
(two uniforms, one log, one sqrt, one sine and one cosine per pair, all SIMD ufuncs in
float32) and costs 3-6 ns per normal.

The transform.  With ``v`` uniform on (0, 1] and ``theta`` uniform on [0, 2 pi),
``r = sqrt(-2 ln v)`` is Rayleigh distributed and ``(r cos theta, r sin theta)`` are two
independent standard normals (Box & Muller 1958).  The only approximation is the
resolution of the uniforms:

* ``theta`` comes from a 24-bit float32 uniform: a 2^24-point grid of angles, so
  ``E cos^2 = 1/2`` and ``E cos^4 = 3/8`` hold exactly and the angular quantisation
  (3.7e-7 rad) is below float32 resolution of the output.
* ``v`` comes from a 24-bit float32 uniform ``1 - u`` on ``{k 2^-24, k = 1 .. 2^24}``.
  Used as is, that grid would cut the tails at ``|z| <= sqrt(48 ln 2) = 5.77`` and
  quantise them coarsely (the grid is relatively coarse near 0).  Every ``v <= 2^-10``
  (probability exactly 2^-10, i.e. ``r^2 >= 20 ln 2``, ``r >= 3.72``) is therefore
  redrawn as ``2^-10 (1 - U)`` with ``U`` a 53-bit float64 uniform: continuous on
  (0, 2^-10], so the tail of ``r^2`` is the exact exponential down to ``v = 2^-63``,
  ``|z| <= 9.35`` (a normal exceeds that with probability 1e-20).  Above the threshold the
  24-bit grid moves ``r`` by at most ``2^-24 / (v r) <= 1.6e-5``, a quantisation of the
  same order as numpy's float32 ziggurat.

So the samples are standard normal to float32 precision in the body and to 53-bit
resolution in the tails; the tests check the moments, the CDF, the exponential law of
``r^2`` and the memoryless tail beyond the threshold against theory.

Layout and reproducibility.  ``out`` is filled in blocks of ``_BLOCK`` samples (2**18:
1 MB, cache sized, and large enough that two threads do not wait on each other for the
GIL between the ~14 numpy calls of a block: with 2**16 two threads drew 1.59x as fast
as one, with 2**18 1.89x); within a block the first half holds ``r sin theta`` and the second half
``r cos theta`` of the same pairs.  The draw sequence depends only on ``out.size`` and the generator's
state, never on threads, so callers keep their spawned-stream layout unchanged.
"""

import numpy as np

from noise.errors import ParameterError

__all__ = ["standard_normal", "standard_normal_rows", "TAIL_V"]

#: Radius uniforms at or below this value are redrawn in float64 (``r >= 3.72``).
TAIL_V = 2.0 ** -10

_BLOCK = 1 << 18
_TAIL32 = np.float32(TAIL_V)
_TWO_PI = np.float32(2.0 * np.pi)


def standard_normal(gen, out):
    """Fill ``out`` with independent float32 standard normals drawn from ``gen``.

    Parameters
    ----------
    gen : numpy.random.Generator
        Source of uniforms (its state advances; the sequence of draws depends only on
        ``out.size``).
    out : ndarray, float32, C-contiguous, any shape
        Filled in place.

    Returns
    -------
    ndarray
        ``out``.
    """
    if not isinstance(out, np.ndarray) or out.dtype != np.float32:
        raise ParameterError(f"'out' must be a float32 ndarray, got "
                             f"{getattr(out, 'dtype', type(out).__name__)}")
    if not out.flags.c_contiguous:
        raise ParameterError("'out' must be C-contiguous")
    flat = out.reshape(-1)
    n = flat.size
    even = n - n % 2
    tmp = np.empty(min(_BLOCK, even) // 2, dtype=np.float32)
    for s in range(0, even, _BLOCK):
        e = min(even, s + _BLOCK)
        h = (e - s) // 2
        v, c = flat[s:s + h], flat[s + h:e]
        gen.random(out=v, dtype=np.float32)
        gen.random(out=c, dtype=np.float32)
        np.subtract(np.float32(1.0), v, out=v)                  # (0, 1], 2^-24 grid
        tail = np.flatnonzero(v <= _TAIL32)
        if tail.size:                                           # exact tails (53-bit)
            v[tail] = (1.0 - gen.random(tail.size)) * TAIL_V
        np.log(v, out=v)
        v *= np.float32(-2.0)
        np.sqrt(v, out=v)                                       # radius r
        c *= _TWO_PI                                            # angle theta
        t = tmp[:h]
        np.sin(c, out=t)
        np.cos(c, out=c)
        c *= v                                                  # r cos(theta)
        v *= t                                                  # r sin(theta)
    if n % 2:
        flat[-1] = gen.standard_normal(dtype=np.float32)
    return out


def standard_normal_rows(gens, out):
    """Fill row ``i`` of ``out`` exactly as ``standard_normal(gens[i], out[i])`` would.

    For many short rows, each from its own stream (a batch of small frames): the
    uniforms are drawn row by row, the transform runs once over all rows (~16 numpy
    calls per batch instead of per row).  Same draws from each generator in the same
    order, same float32 operations on every element: bit-identical to the row loop.

    Parameters
    ----------
    gens : sequence of numpy.random.Generator
        One per row of ``out``.
    out : ndarray, float32, C-contiguous, shape (len(gens), n)
        Filled in place.

    Returns
    -------
    ndarray
        ``out``.
    """
    if not isinstance(out, np.ndarray) or out.dtype != np.float32 or out.ndim != 2:
        raise ParameterError(f"'out' must be a 2-D float32 ndarray, got "
                             f"{getattr(out, 'dtype', type(out).__name__)} "
                             f"{getattr(out, 'shape', '')}")
    if not out.flags.c_contiguous:
        raise ParameterError("'out' must be C-contiguous")
    if len(gens) != out.shape[0]:
        raise ParameterError(f"'gens' must hold one generator per row of 'out': "
                             f"{len(gens)} for {out.shape[0]} rows")
    m, n = out.shape
    if n > _BLOCK or m < 2:                 # several blocks per row: as standard_normal
        for gen, row in zip(gens, out):
            standard_normal(gen, row)
        return out
    h = n // 2
    # the halves of every row side by side in two contiguous buffers (strided
    # ufuncs are ~40 % slower); the products are written into the rows at the end
    v = np.empty((m, h), dtype=np.float32)
    c = np.empty((m, h), dtype=np.float32)
    for gen, vr, cr in zip(gens, v, c):
        gen.random(out=vr, dtype=np.float32)
        gen.random(out=cr, dtype=np.float32)
    np.subtract(np.float32(1.0), v, out=v)
    rows, cols = np.nonzero(v <= _TAIL32)               # row-major: each row in order
    if rows.size:                                       # each row's tail draws, in order
        starts = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]])
        u = np.empty(rows.size)
        for a, b in zip(starts.tolist(), np.r_[starts[1:], rows.size].tolist()):
            gens[rows[a]].random(out=u[a:b])
        v[rows, cols] = (1.0 - u) * TAIL_V
    np.log(v, out=v)
    v *= np.float32(-2.0)
    np.sqrt(v, out=v)
    c *= _TWO_PI
    t = np.sin(c)
    np.cos(c, out=c)
    np.multiply(c, v, out=out[:, h:2 * h])              # r cos(theta)
    np.multiply(v, t, out=out[:, :h])                   # r sin(theta)
    if n % 2:
        for gen, row in zip(gens, out):
            row[-1] = gen.standard_normal(dtype=np.float32)
    return out
