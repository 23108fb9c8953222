"""Random streams: one registry of spawn keys for both packages.

Every random draw of a run comes from its own stream,
``Generator(PCG64(SeedSequence(entropy, spawn_key=key)))``, whose key says what it is
for.  Keys are fixed by *what* is drawn (component, output, integration, chunk, slot),
never by the thread count, chunking or processing order, so adding a component or
changing a chunk size leaves every other stream unchanged (STYLE.md, habits 1-2).
What one stream's draws are may still depend on the scene: the charge engine's Poisson
stream of a chunk draws the pixels that collect charge, in groups sized by the rate
map (:mod:`scenesim.engine`), so a new source changes the arrivals of the others,
though not the noise, hot pixels or cosmic rays.  ``SeedSequence.spawn`` would number
children in creation order; fixed keys make the layout explicit and independent of
which parts a scene switches on.

The tree under a scene's seed (``()`` is the scene's root ``SeedSequence(seed)``)::

    (0,)                      ENGINE: the charge engine's root
    (0, 1)                    ENGINE + NOISE: the noise generator's root
    (0, 1, c, ...)              + noise component c of NOISE_COMPONENTS (below)
    (0, 2, i, chunk)          ENGINE + POISSON: Poisson arrivals of integration i
    (0, 5, i, chunk)          ENGINE + POISSON_2D: the '2d' arrivals shortcut
    (3,)                      COSMIC_RAYS: hits (times, places, charges)
    (4,)                      HOT_PIXELS: which pixels are hot

Under a noise generator's root (``NoiseGenerator(rng=...)``; its root is ``(0, 1)``
in a scene), component ``c`` draws from ``root + (NOISE_COMPONENTS[c], ...)``:
white ``(1, slot, chunk)``, correlated pink ``(2, group)``, uncorrelated pink ``(3,
output, group)``, ACN ``(4, output, even/odd, group)``, picture frame ``(5,
group)``, pedestal ``(6, block)``, kTC and bias ``(7, integration, chunk)``, RTN
``(8, 0)`` (which pixels) and ``(8, 2, slot)`` (transitions), the raw samples that
are not image pixels (interleaved reference samples, reference output) white ``(9, 0,
slot)`` and kTC ``(9, 1, integration)``; ``group`` counts the
1/f synthesis groups of :mod:`noise.pink` from 1.

:class:`KeyedStreams` (on :mod:`noise.fast.seedhash`) builds many of these generators
at once, bit-identical to :func:`generator`: the hash of a fixed key prefix is kept and
the varying last words of many keys go through it together.
"""

import numpy as np

from noise.errors import ParameterError, ParameterTypeError
from noise.fast.seedhash import SeedPools, pcg64
from noise.validate import describe

__all__ = ["ENGINE", "NOISE", "POISSON", "POISSON_2D", "COSMIC_RAYS", "HOT_PIXELS",
           "NOISE_COMPONENTS", "root_seed", "generator", "KeyedStreams"]

#: Largest seed of a scene or of ``scenesim noise --seed``: a signed 64-bit integer,
#: as TOML and a FITS integer card hold it.
MAX_SEED = 2 ** 63 - 1

#: The charge engine's root, under the scene's seed.
ENGINE = (0,)
#: The noise generator's root, under the engine's root.
NOISE = (1,)
#: Poisson arrivals, under the engine's root: ``+ (integration, chunk)``.
POISSON = (2,)
#: The '2d' arrivals shortcut, under the engine's root: ``+ (integration, chunk)``.
POISSON_2D = (5,)
#: Cosmic rays, under the scene's seed.
COSMIC_RAYS = (3,)
#: Hot pixels, under the scene's seed.
HOT_PIXELS = (4,)
#: Noise components and their first key under the noise generator's root.
NOISE_COMPONENTS = {"white": 1, "c_pink": 2, "u_pink": 3, "acn": 4, "pca0": 5,
                    "pedestal": 6, "ktc": 7, "rtn": 8, "raw": 9}


def root_seed(rng):
    """Return ``(entropy, spawn_key)`` of the root ``SeedSequence`` for ``rng``.

    ``rng`` may be an int (>= 0), a ``SeedSequence``, a ``Generator`` (its seed
    sequence is used) or ``None`` (fresh OS entropy, recorded so the run can be
    repeated).
    """
    if isinstance(rng, np.random.Generator):
        ss = rng.bit_generator.seed_seq
    elif isinstance(rng, np.random.SeedSequence):
        ss = rng
    elif rng is None or (isinstance(rng, (int, np.integer)) and not isinstance(rng, bool)):
        if rng is not None and rng < 0:
            raise ParameterError(f"'rng' seed must be >= 0, got {rng!r}")
        ss = np.random.SeedSequence(None if rng is None else int(rng))
    else:
        raise ParameterTypeError(
            f"'rng' must be an int, SeedSequence, Generator or None, got {describe(rng)}")
    return ss.entropy, tuple(ss.spawn_key)


def generator(entropy, key):
    """The stream ``Generator(PCG64(SeedSequence(entropy, spawn_key=key)))``."""
    return np.random.Generator(np.random.PCG64(
        np.random.SeedSequence(entropy, spawn_key=tuple(key))))


def detector_uniform(rng, detector):
    """Uniform [0, 1) values for the pixels of ``detector``'s read-out image, as
    ``rng.random((naxis2, naxis1))`` of the *full* array gives them at those pixels.

    A property of a physical pixel (a telegraph pixel, a hot pixel) drawn this way is
    the same in a window or stripe as in the full frame of one detector and seed (as
    the bias template is, :func:`noise.template.template_for`); on the full array it
    is ``rng.random(shape)`` itself.  A window costs its own pixels only: ``rng``'s
    ``PCG64`` (one 64-bit word per double) is advanced over the pixels outside it.

    Parameters
    ----------
    rng : numpy.random.Generator
        A ``PCG64`` generator (:func:`generator`), used from its current state.
    detector : noise.clock.Detector

    Returns
    -------
    ndarray, shape (ny, nx), float64
    """
    det = detector
    full_nx = det.naxis1
    if (det.y0, det.x0, det.ny, det.nx) == (0, 0, det.naxis2, full_nx):
        return rng.random(det.shape)
    bg = rng.bit_generator
    if not isinstance(bg, np.random.PCG64):
        raise ParameterTypeError(f"'rng' must draw from a PCG64 (it is advanced over "
                                 f"the pixels outside the window), got "
                                 f"{type(bg).__name__}")
    out = np.empty(det.shape)
    bg.advance(det.y0 * full_nx + det.x0)
    skip = full_nx - det.nx
    for y in range(det.ny):
        out[y] = rng.random(det.nx)
        if skip and y + 1 < det.ny:
            bg.advance(skip)
    return out


class KeyedStreams:
    """The streams ``generator(entropy, prefix + suffix)`` of one key prefix, many at once.

    Why: a frame or a read builds tens of streams (one per row chunk, per 1/f series
    and group); one by one, each costs 15-30 us of ``SeedSequence`` hashing that holds
    the GIL, which the other worker thread then waits for.  Here the hash of
    ``prefix`` is computed once and the suffixes of a call go through the rest together
    (:class:`noise.fast.seedhash.SeedPools`): ~2 us per stream.  The generators are
    bit-identical to :func:`generator`'s; a root entropy or a key the vectorised hash
    does not take (a numpy-array entropy, a word >= 2**32) is hashed by numpy's own
    ``SeedSequence``.

    Parameters
    ----------
    entropy : int or sequence of int
        Root entropy, as :func:`root_seed` returns it.
    prefix : sequence of sequence of int
        One key prefix per series (all of the same length); a single prefix for
        one series.
    """

    def __init__(self, entropy, prefix):
        prefix = [tuple(int(w) for w in k) for k in prefix]
        self.entropy, self.prefix = entropy, prefix
        self._pools = (SeedPools.spawn(entropy, prefix)
                       if SeedPools.accepts(entropy, prefix) else None)

    def generators(self, *words):
        """One generator per key ``prefix[s] + words``, for every series ``s``; with a
        single prefix, a 1-D integer array among ``words`` gives one generator per
        element (the words broadcast).  A list in key order."""
        if any(np.ndim(w) > 1 for w in words):
            raise ParameterError(f"'words' must be ints or 1-D arrays, got shapes "
                                 f"{[np.shape(w) for w in words]}")
        lens = [np.size(w) for w in words]
        n = max([len(self.prefix)] + lens)
        if any(k not in (1, n) for k in lens) or len(self.prefix) not in (1, n):
            raise ParameterError(f"'words' must be ints or arrays of one length ({n}), "
                                 f"got lengths {lens} for {len(self.prefix)} prefixes")
        if self._pools is not None and all(SeedPools.accepts_word(w) for w in words):
            pools = self._pools
            for w in words:
                pools = pools.extend(w)
            states = pools.states()
        else:
            cols = [np.ravel(np.asarray(w, dtype=object)) for w in words]
            states = self._numpy_states([self.prefix[i % len(self.prefix)]
                                         + tuple(int(c[i % len(c)]) for c in cols)
                                         for i in range(n)])
        return [np.random.Generator(pcg64(st)) for st in states]

    def states_grid(self, words):
        """``generate_state(4, uint64)`` of the key ``prefix[s] + (w,)`` for every prefix
        ``s`` and every ``w`` of the 1-D integer array ``words``: ndarray, shape
        (len(prefix), len(words), 4), uint64 (seed a stream with
        :func:`noise.fast.seedhash.pcg64`).  Streams of several frames or groups ahead
        in one call."""
        words = np.asarray(words)
        if words.ndim != 1:
            raise ParameterError(f"'words' must be a 1-D integer array, got shape "
                                 f"{words.shape}")
        n, k = len(self.prefix), words.size
        if self._pools is not None and SeedPools.accepts_word(words):
            pools = SeedPools(np.repeat(self._pools.pool, k, axis=1), self._pools.h)
            return pools.extend(np.tile(words, n)).states().reshape(n, k, 4)
        return self._numpy_states([p + (int(w),) for p in self.prefix
                                   for w in words]).reshape(n, k, 4)

    def _numpy_states(self, keys):
        """numpy's own ``generate_state(4, uint64)`` of each key (the fallback)."""
        return np.array([np.random.SeedSequence(self.entropy, spawn_key=key)
                         .generate_state(4, np.uint64) for key in keys],
                        dtype=np.uint64).reshape(len(keys), 4)
