"""noise.fast.seedhash: the vectorised SeedSequence hash equals numpy's, word for word."""

import numpy as np
import pytest

from noise.fast.seedhash import spawned_generators, spawned_states

CASES = [
    (123456789012345678901234567890, ()),          # 97-bit entropy, no prefix
    (2 ** 127 + 5, (1, 2, 3)),
    (0, ()),
    (5, (3,)),
    ([1, 2 ** 40], (7, 2 ** 33)),                  # list entropy, wide prefix words
]
KEYS = np.array([[1, s, c] for s in (0, 1, 5, 2 ** 31, 2 ** 32 - 1) for c in (0, 9)])


@pytest.mark.parametrize("entropy, prefix", CASES)
def test_states_equal_numpy(entropy, prefix):
    got = spawned_states(entropy, prefix, KEYS)
    want = np.array([np.random.SeedSequence(entropy, spawn_key=prefix + tuple(map(int, k)))
                     .generate_state(4, np.uint64) for k in KEYS])
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("entropy, prefix", CASES[:2])
def test_generators_draw_what_numpy_draws(entropy, prefix):
    mine = spawned_generators(entropy, prefix, KEYS[:4])
    ref = [np.random.Generator(np.random.PCG64(np.random.SeedSequence(
        entropy, spawn_key=prefix + tuple(map(int, k))))) for k in KEYS[:4]]
    for a, b in zip(mine, ref):
        np.testing.assert_array_equal(a.random(100), b.random(100))


def test_no_spawn_key_at_all():
    got = spawned_states(99, (), np.zeros((1, 0), dtype=int))[0]
    np.testing.assert_array_equal(got, np.random.SeedSequence(99).generate_state(4, np.uint64))


@pytest.mark.parametrize("keys", [np.array([[-1]]), np.array([[2 ** 32]]), np.array([1, 2])])
def test_bad_keys(keys):
    with pytest.raises(ValueError, match="'keys'"):
        spawned_states(1, (), keys)


def test_bad_entropy():
    with pytest.raises(ValueError, match="'entropy'"):
        spawned_states(np.array([1, 2]), (), np.zeros((1, 1), dtype=int))
    with pytest.raises(ValueError, match=">= 0"):
        spawned_states(-3, (), np.zeros((1, 1), dtype=int))
