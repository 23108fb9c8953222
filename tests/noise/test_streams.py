"""Tests of :mod:`noise.streams`: the one registry of spawn keys.

The documented tree (``noise/streams.py``) is checked against what the packages draw:
a scene engine's noise comes from ``ENGINE + NOISE`` under the scene seed, a noise
component from ``root + (NOISE_COMPONENTS[name], ...)``.
"""

import numpy as np
import pytest

import noise
from noise import streams
from noise.errors import ParameterError
from scenesim.detector.readout import Readout
from scenesim.engine import ChargeEngine


def test_generator_is_the_seed_sequence_stream():
    g = streams.generator(123, (4, 5))
    ref = np.random.Generator(np.random.PCG64(np.random.SeedSequence(123,
                                                                     spawn_key=(4, 5))))
    assert g.integers(0, 2 ** 62, 8).tolist() == ref.integers(0, 2 ** 62, 8).tolist()


def test_engine_noise_is_drawn_under_engine_plus_noise():
    det = noise.preset("H2RG", naxis1=64, naxis2=64)
    params = noise.NIRSPEC_DEFAULTS
    seed = 77
    eng = ChargeEngine(det, Readout.from_reads([[0], [1]]), noise_params=params,
                       rng=np.random.SeedSequence(seed, spawn_key=streams.ENGINE))
    with eng.simulate(save_noise=True) as run:
        got = [res.noise for res in run]
    gen = noise.NoiseGenerator(det, params, rng=np.random.SeedSequence(
        seed, spawn_key=streams.ENGINE + streams.NOISE))
    want = [f.copy() for *_, f in gen.frames(2)]
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)


def test_keys_are_distinct():
    keys = [streams.ENGINE, streams.COSMIC_RAYS, streams.HOT_PIXELS]
    assert len(set(keys)) == len(keys)
    under_engine = [streams.NOISE, streams.POISSON, streams.POISSON_2D]
    assert len(set(under_engine)) == len(under_engine)
    assert len(set(streams.NOISE_COMPONENTS.values())) == len(streams.NOISE_COMPONENTS)


@pytest.mark.parametrize("bad", [-1, 1.5, "7", True])
def test_root_seed_rejects_bad_seeds(bad):
    with pytest.raises(ParameterError, match="'rng'"):
        streams.root_seed(bad)
