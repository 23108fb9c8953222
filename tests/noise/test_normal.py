"""noise.fast.normal: the Box-Muller sampler against the standard normal law."""

import numpy as np
import pytest
from scipy import stats

from noise.errors import ParameterError
from noise.fast.normal import TAIL_V, _BLOCK, standard_normal, standard_normal_rows

N = 4_000_000


@pytest.fixture(scope="module")
def z():
    out = np.empty(N, dtype=np.float32)
    return standard_normal(np.random.default_rng(2024), out).astype(np.float64)


def test_moments(z):
    # For N i.i.d. N(0,1): SE(mean) = 1/sqrt(N), SE(var) = sqrt(2/N),
    # SE(excess kurtosis) = sqrt(24/N); 5 sigma each.
    assert abs(z.mean()) < 5 / np.sqrt(N)
    assert abs(z.var() - 1.0) < 5 * np.sqrt(2.0 / N)
    assert abs(stats.kurtosis(z)) < 5 * np.sqrt(24.0 / N)
    assert abs(stats.skew(z)) < 5 * np.sqrt(6.0 / N)


def test_cdf_and_tail_counts(z):
    # Kolmogorov-Smirnov against Phi: p-value above 1e-4 (a false alarm 1 time in 1e4).
    assert stats.kstest(z[:1_000_000], "norm").pvalue > 1e-4
    # Two-sided tail counts beyond 3, 4 and 4.5 sigma: binomial counts, 5 sigma each.
    for k in (3.0, 4.0, 4.5):
        p = 2 * stats.norm.sf(k)
        n = np.count_nonzero(np.abs(z) > k)
        assert abs(n - N * p) < 5 * np.sqrt(N * p) + 1, (k, n, N * p)


def test_pairs_radius_is_exponential_and_tail_is_memoryless():
    # Within a block, sample i of the first half and sample i of the second half are the
    # (r sin, r cos) of one pair, so r^2 = a^2 + b^2 ~ Exp(mean 2): P(r^2 > t) = e^(-t/2).
    nblk = -(-(1 << 23) // _BLOCK)                           # >= 2**23 samples
    out = np.empty(nblk * _BLOCK, dtype=np.float32)
    standard_normal(np.random.default_rng(7), out)
    blk = out.reshape(nblk, 2, _BLOCK // 2).astype(np.float64)
    r2 = (blk[:, 0] ** 2 + blk[:, 1] ** 2).ravel()
    m = r2.size                                              # >= 4.2e6 pairs
    # mean of Exp(2) is 2 with SE 2/sqrt(m)
    assert abs(r2.mean() - 2.0) < 5 * 2.0 / np.sqrt(m)
    # The tail branch: r^2 >= -2 ln(TAIL_V) has probability TAIL_V exactly (binomial
    # count, 5 sigma) ...
    t = -2.0 * np.log(TAIL_V)
    tail = r2[r2 >= t] - t
    assert abs(tail.size - m * TAIL_V) < 5 * np.sqrt(m * TAIL_V * (1 - TAIL_V))
    # ... and, Exp being memoryless, the excess over the threshold is again Exp(mean 2)
    # (mean 2, SE 2/sqrt(n)); a truncated or grid-quantised tail would fail the
    # conditional law: KS test of the excess against Exp(scale 2), p > 1e-4.
    assert abs(tail.mean() - 2.0) < 5 * 2.0 / np.sqrt(tail.size)
    assert stats.kstest(tail, "expon", args=(0, 2.0)).pvalue > 1e-4
    # The tail is continuous (53-bit), not the 2^-24 grid: on the grid, r^2 above the
    # threshold could take only 2^14 values; here nearly every sample is distinct.
    assert np.unique(tail).size > 0.99 * tail.size


def test_sequence_depends_only_on_size_and_odd_lengths():
    a = standard_normal(np.random.default_rng(3), np.empty((5, 7), dtype=np.float32))
    b = standard_normal(np.random.default_rng(3), np.empty(35, dtype=np.float32))
    np.testing.assert_array_equal(a.ravel(), b)
    assert np.all(np.isfinite(a))


def test_bad_out():
    with pytest.raises(ParameterError, match="'out' must be a float32"):
        standard_normal(np.random.default_rng(0), np.empty(4))
    with pytest.raises(ParameterError, match="C-contiguous"):
        standard_normal(np.random.default_rng(0), np.empty((4, 4), np.float32)[:, ::2])


@pytest.mark.parametrize("m, n", [(32, 4096), (7, 4097), (3, 1000), (5, 2), (4, 1),
                                  (1, 512), (3, _BLOCK + 10)])
def test_rows_equal_one_call_per_row(m, n):
    """Row i is exactly standard_normal(gens[i], out[i]) and leaves gens[i] in the same
    state (tails included: 32 x 2048 pairs hold ~64 radius redraws)."""
    loop = [np.random.default_rng([9, k]) for k in range(m)]
    rows = [np.random.default_rng([9, k]) for k in range(m)]
    a = np.empty((m, n), dtype=np.float32)
    for gen, row in zip(loop, a):
        standard_normal(gen, row)
    b = standard_normal_rows(rows, np.empty((m, n), dtype=np.float32))
    np.testing.assert_array_equal(a, b)
    assert [g.random() for g in loop] == [g.random() for g in rows]


def test_rows_bad_arguments():
    gens = [np.random.default_rng(k) for k in range(2)]
    with pytest.raises(ParameterError, match="2-D float32"):
        standard_normal_rows(gens, np.empty(8, dtype=np.float32))
    with pytest.raises(ParameterError, match="2-D float32"):
        standard_normal_rows(gens, np.empty((2, 4)))
    with pytest.raises(ParameterError, match="C-contiguous"):
        standard_normal_rows(gens, np.empty((2, 8), dtype=np.float32)[:, ::2])
    with pytest.raises(ParameterError, match="one generator per row"):
        standard_normal_rows(gens[:1], np.empty((2, 8), dtype=np.float32))
