"""noise.fast.memory: the malloc policy is applied on glibc and changes no result."""

import sys

import numpy as np
import pytest

from noise import NoiseGenerator, NoiseParams, preset
from noise.fast.memory import keep_freed_memory


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc only")
def test_keep_freed_memory_applies_and_changes_no_frame():
    det = preset("H2RG", naxis1=64, naxis2=64, n_out=2)
    before = NoiseGenerator(det, NoiseParams(), rng=5, threads=1).cube(2)
    assert keep_freed_memory() is True          # mallopt returned success
    after = NoiseGenerator(det, NoiseParams(), rng=5, threads=1).cube(2)
    np.testing.assert_array_equal(before, after)
