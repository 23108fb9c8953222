"""Random streams: one registry of spawn keys for both packages.

Every random draw of a run comes from its own stream,
``Generator(PCG64(SeedSequence(entropy, spawn_key=key)))``, whose key says what it
is for.  Keys are fixed by *what* is drawn (component, output, integration, chunk,
slot), never by the thread count, chunking or processing order, so adding a
component or changing a chunk size leaves every other draw unchanged (STYLE.md,
habits 1-2).  ``SeedSequence.spawn`` would number children in creation order; fixed
keys make the layout explicit and independent of which parts a scene switches on.

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

:func:`noise.fast.seedhash.spawned_generators` builds many of these generators at
once, bit-identical to :func:`generator`.
"""

import numpy as np

from noise.errors import ParameterError, ParameterTypeError
from noise.validate import describe

__all__ = ["ENGINE", "NOISE", "POISSON", "POISSON_2D", "COSMIC_RAYS", "HOT_PIXELS",
           "NOISE_COMPONENTS", "root_seed", "generator"]

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
