"""Many spawned random streams at once: numpy's ``SeedSequence`` hashing, vectorised.

Why: every frame of a window draws its white noise from its own stream, keyed
``(white, slot, chunk)``, so that the values depend only on the slot.  Building one
``Generator(PCG64(SeedSequence(entropy, spawn_key=key)))`` costs 12-19 us, mostly the
hashing, done in Python-level loops per key; a 300-integration time series builds
thousands.  The hash is a fixed function of 32-bit words, so the keys of a whole
batch can go through it together as uint32 arrays.

The algorithm (O'Neill's seed_seq, as numpy's ``SeedSequence`` implements it, pool of 4
words; all arithmetic modulo 2**32):

* the entropy words are the root entropy as little-endian 32-bit words, zero-padded to
  the pool size when there is a spawn key, followed by one word per spawn-key element
  (more for elements >= 2**32: those keys are left to numpy here);
* ``hashmix(v)``: ``v ^= h; h *= MULT_A; v *= h; v ^= v >> 16`` with ``h`` starting
  at ``INIT_A``; the pool is the first 4 words hashed, then every word mixed into every
  other (``mix(x, y) = (MIX_L x - MIX_R y) ^ (... >> 16)``), then the remaining entropy
  words mixed into all 4;
* ``generate_state(4, uint64)``: 8 words ``p ^= h; h *= MULT_B; p *= h; p ^= p >> 16``
  cycling over the pool with ``h`` starting at ``INIT_B``, read as 4 little-endian
  uint64.

The result is tested word for word against ``numpy.random.SeedSequence``; a
:class:`PCG64` seeded from these words is the generator numpy would build.
"""

import numpy as np
from numpy.random.bit_generator import ISeedSequence

from noise.errors import ParameterError

__all__ = ["spawned_generators", "spawned_states"]

_INIT_A = np.uint32(0x43B0D7E5)
_MULT_A = np.uint32(0x931E8875)
_INIT_B = np.uint32(0x8B51F9DD)
_MULT_B = np.uint32(0x58F38DED)
_MIX_L = np.uint32(0xCA01F9DD)
_MIX_R = np.uint32(0x4973F715)
_SHIFT = np.uint32(16)
_POOL = 4


def _words(value):
    """Little-endian 32-bit words of a non-negative int (``[0]`` for 0)."""
    value = int(value)
    if value < 0:
        raise ParameterError(f"seed words must be >= 0, got {value}")
    out = [value & 0xFFFFFFFF]
    value >>= 32
    while value:
        out.append(value & 0xFFFFFFFF)
        value >>= 32
    return out


def _entropy_words(entropy):
    if isinstance(entropy, (list, tuple)):
        return [w for e in entropy for w in _words(e)]
    if isinstance(entropy, (int, np.integer)):
        return _words(entropy)
    raise ParameterError(f"'entropy' must be an int or a list/tuple of ints, got "
                     f"{type(entropy).__name__}")


class _Hash:
    """The running hash constant of ``hashmix``, one per key (broadcast)."""

    def __init__(self, n):
        self.h = np.full(n, _INIT_A, dtype=np.uint32)

    def mix(self, value):
        value = value ^ self.h
        self.h *= _MULT_A
        value *= self.h
        value ^= value >> _SHIFT
        return value


def _mix(x, y):
    r = _MIX_L * x - _MIX_R * y
    r ^= r >> _SHIFT
    return r


def spawned_states(entropy, prefix, keys):
    """``SeedSequence(entropy, spawn_key=prefix + tuple(k)).generate_state(4, uint64)``
    for every row ``k`` of ``keys``.

    Parameters
    ----------
    entropy : int or list/tuple of int
        Root entropy (non-negative; numpy arrays are not accepted: numpy coerces
        their elements differently).
    prefix : tuple of int
        Common spawn-key prefix.
    keys : array_like of int, shape (n, m)
        Key suffixes, each element in ``[0, 2**32)``.

    Returns
    -------
    ndarray, shape (n, 4), uint64
    """
    keys = np.asarray(keys, dtype=np.int64)
    if keys.ndim != 2 or (keys.size and (keys.min() < 0 or keys.max() >= 1 << 32)):
        raise ParameterError(f"'keys' must be a 2-D array of integers in [0, 2**32), got "
                             f"shape {keys.shape}")
    n = keys.shape[0]
    run = _entropy_words(entropy)
    spawn = [w for p in prefix for w in _words(p)]
    if spawn or keys.shape[1]:
        run = run + [0] * max(0, _POOL - len(run))
    fixed = np.array(run + spawn, dtype=np.uint32)
    words = np.concatenate([np.broadcast_to(fixed, (n, fixed.size)),
                            keys.astype(np.uint32)], axis=1)
    nw = words.shape[1]
    h = _Hash(n)
    with np.errstate(over="ignore"):
        pool = [h.mix(words[:, i] if i < nw else np.zeros(n, np.uint32))
                for i in range(_POOL)]
        for src in range(_POOL):
            for dst in range(_POOL):
                if src != dst:
                    pool[dst] = _mix(pool[dst], h.mix(pool[src]))
        for src in range(_POOL, nw):
            for dst in range(_POOL):
                pool[dst] = _mix(pool[dst], h.mix(words[:, src]))
        state = np.empty((n, 8), dtype=np.uint32)
        hb = np.full(n, _INIT_B, dtype=np.uint32)
        for i in range(8):
            v = pool[i % _POOL] ^ hb
            hb *= _MULT_B
            v *= hb
            v ^= v >> _SHIFT
            state[:, i] = v
    return state.astype("<u4").view("<u8").astype(np.uint64)


class _Fixed(ISeedSequence):
    """A seed sequence that hands out precomputed ``generate_state(4, uint64)`` words."""

    def __init__(self, words):
        self._words = words

    def generate_state(self, n_words, dtype=np.uint32):
        if n_words != 4 or np.dtype(dtype) != np.uint64:
            raise ParameterError("only generate_state(4, uint64) is precomputed, got "
                                 f"({n_words}, {np.dtype(dtype)})")
        return self._words


def spawned_generators(entropy, prefix, keys):
    """``Generator(PCG64(SeedSequence(entropy, spawn_key=prefix + tuple(k))))`` for
    every row ``k`` of ``keys`` (see :func:`spawned_states`), as a list."""
    states = spawned_states(entropy, prefix, keys)
    return [np.random.Generator(np.random.PCG64(_Fixed(s))) for s in states]
