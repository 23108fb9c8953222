"""noise.fast.seedhash and noise.streams.KeyedStreams: the vectorised SeedSequence hash
equals numpy's, word for word, and the streams built from it draw what numpy's draw."""

import numpy as np
import pytest

from noise.errors import ParameterError
from noise.fast.seedhash import SeedPools
from noise.streams import KeyedStreams, generator

CASES = [
    (123456789012345678901234567890, ()),          # 97-bit entropy, no prefix
    (2 ** 127 + 5, (1, 2, 3)),
    (0, ()),
    (5, (3,)),
    ([1, 2 ** 40], (7, 2 ** 33)),                  # list entropy, wide prefix words
]
WORDS = (0, 1, 5, 2 ** 31, 2 ** 32 - 1)


@pytest.mark.parametrize("entropy, prefix", CASES)
def test_states_equal_numpy(entropy, prefix):
    # keys prefix + (1, s, c): the prefix hashed once (or numpy's own hash where the
    # prefix has a word >= 2**32), then s, then every c of the grid at once
    for s in WORDS:
        got = KeyedStreams(entropy, [prefix + (1, s)]).states_grid(np.array([0, 9]))[0]
        want = np.array([np.random.SeedSequence(entropy, spawn_key=prefix + (1, s, c))
                         .generate_state(4, np.uint64) for c in (0, 9)])
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("entropy, prefix", CASES[:2])
def test_generators_draw_what_numpy_draws(entropy, prefix):
    mine = KeyedStreams(entropy, [prefix + (1,)]).generators(np.array(WORDS[:4]), 9)
    ref = [np.random.Generator(np.random.PCG64(np.random.SeedSequence(
        entropy, spawn_key=prefix + (1, s, 9)))) for s in WORDS[:4]]
    for a, b in zip(mine, ref):
        np.testing.assert_array_equal(a.random(100), b.random(100))


def test_no_spawn_key_at_all():
    got = SeedPools.spawn(99, np.zeros((1, 0), dtype=int)).states()[0]
    np.testing.assert_array_equal(got, np.random.SeedSequence(99).generate_state(4, np.uint64))


@pytest.mark.parametrize("keys", [np.array([[-1]]), np.array([[2 ** 32]]), np.array([1, 2])])
def test_bad_keys(keys):
    with pytest.raises(ParameterError, match="'keys'"):
        SeedPools.spawn(1, keys)


def test_bad_entropy():
    with pytest.raises(ParameterError, match="'entropy'"):
        SeedPools.spawn(np.array([1, 2]), np.zeros((1, 1), dtype=int))
    with pytest.raises(ParameterError, match=">= 0"):
        SeedPools.spawn(-3, np.zeros((1, 1), dtype=int))


@pytest.mark.parametrize("word", [-1, 2 ** 32, np.array([[1, 2]]), 1.5, True])
def test_bad_words(word):
    with pytest.raises(ParameterError, match="'word'"):
        SeedPools.spawn(1, [(1,)]).extend(word)


# ----------------------------------------------------------------- SeedPools, KeyedStreams


def _numpy_state(entropy, key):
    return np.random.SeedSequence(entropy, spawn_key=tuple(map(int, key))) \
        .generate_state(4, np.uint64)


@pytest.mark.parametrize("entropy", [7, 2 ** 127 + 5, 123456789012345678901234567890 ** 2,
                                     [1, 2 ** 40], (0,)])
def test_pools_extended_word_by_word_equal_numpy(entropy):
    # the pool of a key, extended by more words, is the pool of the longer key: for
    # keys of 1 to 4 words, each further word of three (one per key, or one for all)
    keys = [(3,), (0,), (2 ** 32 - 1,)]
    pools = SeedPools.spawn(entropy, keys)
    words = [np.array([5, 0, 2 ** 31]), 9, np.array([1, 1, 4])]
    for depth in range(len(words) + 1):
        full = [k + tuple(int(np.broadcast_to(w, (3,))[i]) for w in words[:depth])
                for i, k in enumerate(keys)]
        want = np.array([_numpy_state(entropy, k) for k in full])
        np.testing.assert_array_equal(pools.states(), want)
        if depth < len(words):
            pools = pools.extend(words[depth])


def test_one_pool_broadcasts_over_an_array_of_words():
    pools = SeedPools.spawn(11, [(1, 2)]).extend(np.arange(6))
    want = np.array([_numpy_state(11, (1, 2, i)) for i in range(6)])
    np.testing.assert_array_equal(pools.states(), want)


@pytest.mark.parametrize("entropy, keys, ok", [
    (5, [(1,)], True),
    ([1, 2], [(1, 2), (3, 4)], True),
    (np.uint64(5), [(1,)], True),
    (5, [()], False),                    # an empty key skips numpy's zero padding
    (5, [], False),
    (5, [(1,), (1, 2)], False),          # keys of different lengths
    (5, [(2 ** 32,)], False),            # a key element of two words
    (5, [(-1,)], False),
    (-5, [(1,)], False),
    (True, [(1,)], False),
    (np.array([1, 2]), [(1,)], False),   # numpy coerces arrays' elements differently
    ([], [(1,)], False),
])
def test_pools_accept_only_what_they_reproduce(entropy, keys, ok):
    assert SeedPools.accepts(entropy, keys) is ok


@pytest.mark.parametrize("word, ok", [(0, True), (2 ** 32 - 1, True), (2 ** 32, False),
                                      (-1, False), (np.arange(3), True),
                                      (np.ones((2, 2), int), False), (1.5, False)])
def test_pools_accept_words_in_range(word, ok):
    assert SeedPools.accepts_word(word) is ok


@pytest.mark.parametrize("entropy", [5, 2 ** 127 + 3, [1, 2 ** 40], np.array([3, 4])])
def test_keyed_streams_draw_what_generator_draws(entropy):
    # the vectorised path (int and list entropy) and numpy's own (array entropy)
    one = KeyedStreams(entropy, [(0, 1, 1)])
    for i, g in enumerate(one.generators(7, np.arange(5))):
        np.testing.assert_array_equal(g.random(8),
                                      generator(entropy, (0, 1, 1, 7, i)).random(8))
    many = KeyedStreams(entropy, [(0, 1, 3, s, 0) for s in range(4)])
    for s, g in enumerate(many.generators(9)):
        np.testing.assert_array_equal(g.bit_generator.random_raw(8),
                                      generator(entropy, (0, 1, 3, s, 0, 9))
                                      .bit_generator.random_raw(8))


def test_keyed_streams_fall_back_for_wide_words():
    got = KeyedStreams(5, [(1,)]).generators(2 ** 33)
    np.testing.assert_array_equal(got[0].random(4), generator(5, (1, 2 ** 33)).random(4))


@pytest.mark.parametrize("words", [(np.arange(3), np.arange(4)), (np.ones((2, 2), int),)])
def test_keyed_streams_refuse_words_that_do_not_line_up(words):
    with pytest.raises(ParameterError, match="'words'"):
        KeyedStreams(5, [(1,)]).generators(*words)
    with pytest.raises(ParameterError, match="'words'"):
        KeyedStreams(5, [(1,), (2,)]).generators(np.arange(3))
