"""Many spawned random streams at once: numpy's ``SeedSequence`` hashing, vectorised.

Why: every frame of a window draws its white noise from its own stream, keyed
``(white, slot, chunk)``, so that the values depend only on the slot.  Building one
``Generator(PCG64(SeedSequence(entropy, spawn_key=key)))`` costs 12-19 us, mostly the
hashing, done in Python-level loops per key; a 300-integration time series builds
thousands; a full frame builds one per 64-row chunk and one per 1/f series and group,
and in the worker threads that hashing holds the GIL (issue 16: 28 % of the time a
one-thread noise run held the GIL was stream construction).  The hash is a fixed
function of 32-bit words, so the keys of a whole batch can go through it together as
uint32 arrays, and since every pool word past the fourth is mixed in by the same four
steps, the pool after a fixed key prefix can be kept and extended
(:class:`SeedPools`).

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

import functools

import numpy as np
from numpy.random.bit_generator import ISeedSequence

from noise.errors import ParameterError

__all__ = ["SeedPools", "pcg64"]

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


def _natural(value):
    """An int (Python or numpy, not bool) >= 0."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= 0


def _entropy_words(entropy):
    if isinstance(entropy, (list, tuple)):
        return [w for e in entropy for w in _words(e)]
    if isinstance(entropy, (int, np.integer)):
        return _words(entropy)
    raise ParameterError(f"'entropy' must be an int or a list/tuple of ints, got "
                     f"{type(entropy).__name__}")


@functools.lru_cache(maxsize=256)
def _steps(h, k, mult):
    """``k`` steps of a hash constant: the constants before and after each step (uint32
    columns, shape (k, 1), read-only) and the constant after the last one (Python int).
    Cached: the constants depend only on how many words were hashed before."""
    seq = [h]
    for _ in range(k):
        seq.append(seq[-1] * mult & 0xFFFFFFFF)
    before = np.array(seq[:-1], dtype=np.uint32)[:, None]
    after = np.array(seq[1:], dtype=np.uint32)[:, None]
    before.flags.writeable = after.flags.writeable = False
    return before, after, seq[-1]


def _hashmix(value, before, after):
    """``hashmix`` of ``value`` with the constants of one step each (broadcast)."""
    value = (value ^ before) * after
    value ^= value >> _SHIFT
    return value


def _mix(x, y):
    r = _MIX_L * x - _MIX_R * y
    r ^= r >> _SHIFT
    return r


class SeedPools:
    """The entropy pools of many ``SeedSequence`` objects that share their root entropy,
    after their spawn keys: extend them by more key words, then seed generators.

    Why: a spawned stream's key is a fixed prefix (exposure, component, series) and a
    last word or two that change per frame or per block.  The pool after the fixed part
    is kept; each new word costs ~9 numpy calls for all keys together.  With every
    pool word past the first four mixed in by the same four steps, extending the pool of
    ``prefix`` by the words of ``suffix`` is exactly the pool of ``prefix + suffix``.

    Parameters
    ----------
    pool : ndarray, uint32, shape (4, n)
        One column per key.
    h : int
        The ``hashmix`` constant after those keys (the same for every key: it depends
        only on the number of words hashed).
    """

    __slots__ = ("pool", "h")

    def __init__(self, pool, h):
        self.pool = pool
        self.h = h

    @staticmethod
    def accepts(entropy, keys):
        """Whether :meth:`spawn` takes ``entropy`` and ``keys`` and its pools may be
        extended (else use numpy's ``SeedSequence``): an int >= 0 or a non-empty
        list/tuple of them, and non-empty keys of one length, of ints in ``[0, 2**32)``
        (an empty key would skip the zero padding that a longer key gets)."""
        if not (_natural(entropy) or (isinstance(entropy, (list, tuple)) and entropy
                                      and all(map(_natural, entropy)))):
            return False
        keys = [tuple(k) for k in keys]
        return (bool(keys) and len({len(k) for k in keys}) == 1 and len(keys[0]) > 0
                and all(_natural(w) and w < 1 << 32 for k in keys for w in k))

    @staticmethod
    def accepts_word(word):
        """Whether :meth:`extend` takes ``word``: an int or 1-D integer array in
        ``[0, 2**32)``."""
        w = np.asarray(word)
        return bool(w.dtype.kind in "iu" and w.ndim <= 1
                    and (w.size == 0 or (w.min() >= 0 and w.max() < 1 << 32)))

    @classmethod
    def spawn(cls, entropy, keys):
        """Pools of ``SeedSequence(entropy, spawn_key=k)`` for every row ``k`` of ``keys``
        (array_like of int, shape (n, m), elements in ``[0, 2**32)``)."""
        keys = np.asarray(keys, dtype=np.int64)
        if keys.ndim != 2 or (keys.size and (keys.min() < 0 or keys.max() >= 1 << 32)):
            raise ParameterError(f"'keys' must be a 2-D array of integers in [0, 2**32), "
                                 f"got shape {keys.shape}")
        run = _entropy_words(entropy)
        if keys.shape[1]:
            run = run + [0] * max(0, _POOL - len(run))
        words = np.concatenate([np.broadcast_to(np.array(run, dtype=np.uint32),
                                                (keys.shape[0], len(run))),
                                keys.astype(np.uint32)], axis=1).T
        nw = words.shape[0]
        before, after, h = _steps(int(_INIT_A), _POOL, int(_MULT_A))
        first = np.zeros((_POOL, keys.shape[0]), dtype=np.uint32)
        first[:min(nw, _POOL)] = words[:_POOL]
        pool = list(_hashmix(first, before, after))
        for src in range(_POOL):
            for dst in range(_POOL):
                if src != dst:
                    b, a, h = _steps(h, 1, int(_MULT_A))
                    pool[dst] = _mix(pool[dst], _hashmix(pool[src], b[0], a[0]))
        pools = cls(np.stack(pool), h)
        for src in range(_POOL, nw):
            pools = pools.extend(words[src])
        return pools

    def extend(self, word):
        """The pools after one more spawn-key word per key: ``word`` an int in
        ``[0, 2**32)`` or an integer array of shape (n,); with a single pool, any
        length (the one key extended by each word)."""
        if not SeedPools.accepts_word(word):
            w = np.asarray(word)
            raise ParameterError(f"'word' must be an integer or a 1-D integer array in "
                                 f"[0, 2**32), got {w.dtype} of shape {w.shape}"
                                 + (f": {w.tolist()!r}" if w.size <= 8 else ""))
        word = np.asarray(word)
        before, after, h = _steps(self.h, _POOL, int(_MULT_A))
        return SeedPools(_mix(self.pool, _hashmix(word.astype(np.uint32), before, after)), h)

    def states(self):
        """``generate_state(4, uint64)`` of every pool: ndarray (n, 4), uint64."""
        before, after, _ = _steps(int(_INIT_B), 2 * _POOL, int(_MULT_B))
        v = _hashmix(np.concatenate([self.pool, self.pool]), before, after)
        lo, hi = v[0::2].astype(np.uint64), v[1::2].astype(np.uint64)
        return np.ascontiguousarray((lo | hi << np.uint64(32)).T)


class _Fixed(ISeedSequence):
    """A seed sequence that hands out precomputed ``generate_state(4, uint64)`` words."""

    def __init__(self, words):
        self._words = words

    def generate_state(self, n_words, dtype=np.uint32):
        if n_words != 4 or np.dtype(dtype) != np.uint64:
            raise ParameterError("only generate_state(4, uint64) is precomputed, got "
                                 f"({n_words}, {np.dtype(dtype)})")
        return self._words


def pcg64(state):
    """The ``PCG64`` that ``SeedSequence`` words ``state`` (``generate_state(4, uint64)``,
    e.g. a row of :meth:`SeedPools.states`) seed."""
    return np.random.PCG64(_Fixed(state))
