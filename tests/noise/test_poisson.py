"""Tests of noise.fast.poisson against the Poisson law (moments, pmf, tail guard)."""

import math

import numpy as np
import pytest
from scipy import stats

from noise.errors import ParameterError
from noise.fast.poisson import (GUIDE_BITS, NUMPY_BELOW, OTHERS_NUMPY_BELOW, guide_table,
                               k_max, k_max_exact,
                               poisson)

N = 200_000


def _means(lam, n, path):
    """``n`` means of ``lam``: all equal ('shared': the guide-table path), or cycling
    through lam * (1 - 1e-12, 1, 1 + 1e-12) so that no value holds half of them
    ('search': the sequential-search inversion / numpy).  The 1e-12 changes no
    moment at the precision tested."""
    if path == "shared":
        return np.full(n, lam)
    return lam * (1.0 + 1e-12 * (np.arange(n) % 3 - 1.0))


@pytest.mark.parametrize("path", ["shared", "search"])
@pytest.mark.parametrize("lam", [1e-3, 0.025, 0.1, 0.3, 1.0, 3.0, 9.9, 10.1, 30.0, 100.0,
                                 1e4])
def test_mean_and_variance(lam, path):
    g = np.random.default_rng(20240611)
    x = poisson(g, _means(lam, N, path))
    assert x.dtype == np.int64 and x.shape == (N,)
    # Sample mean: sd sqrt(lam / N); 5 sigma.
    assert abs(x.mean() - lam) < 5 * math.sqrt(lam / N)
    # Sample variance of a Poisson sample: Var(s^2) ~ (mu4 - sigma^4) / N
    # = (lam + 3 lam^2 - lam^2) / N = (lam + 2 lam^2) / N; 5 sigma.
    assert abs(x.var(ddof=1) - lam) < 5 * math.sqrt((lam + 2 * lam ** 2) / N)


@pytest.mark.parametrize("path", ["shared", "search"])
@pytest.mark.parametrize("lam", [3.0, 0.5, 30.0, 100.0])
def test_pmf_chi_square(lam, path):
    # Fixed seed: the test fails for this seed only if the draws are off; a correct
    # sampler would fail a fresh seed with probability 1e-4.
    g = np.random.default_rng(777)
    x = poisson(g, _means(lam, N, path))
    pmf = stats.poisson(lam)
    # Bins k = kmin..kmax with expected count >= 20 each; both tails pooled into one
    # bin each (k < kmin, k > kmax).
    ok = np.flatnonzero(N * pmf.pmf(np.arange(400)) >= 20)
    kmin, kmax = int(ok.min()), int(ok.max())
    obs = np.bincount(np.clip(x, kmin - 1, kmax + 1) - (kmin - 1), minlength=kmax - kmin + 3)
    exp = N * np.concatenate([[pmf.cdf(kmin - 1)], pmf.pmf(np.arange(kmin, kmax + 1)),
                              [pmf.sf(kmax)]])
    if kmin == 0:                      # no lower tail bin
        obs, exp = obs[1:], exp[1:]
    assert obs.sum() == N and kmax - kmin >= 4
    assert stats.chisquare(obs, exp).pvalue > 1e-4


def test_guard_tail_below_1e15():
    # The inversion stops after k_max passes; what is left must have mass < 1e-15.
    for lam in (1e-3, 0.1, 1.0, 3.0, 9.9, 10.0, 50.0):
        k = k_max(lam)
        assert stats.poisson(lam).sf(k) < 1e-15
        # the exact bound is not wasteful: two passes fewer would leave more than
        # 1e-15; the cached cap (mean rounded up to 1/64) is never below it
        k0 = k_max_exact(lam)
        assert k0 < 2 or stats.poisson(lam).sf(k0 - 2) > 1e-15
        assert k >= k0 and stats.poisson(np.ceil(lam * 64) / 64).sf(k) < 1e-15


def test_mixed_array_keeps_order_and_shape():
    g = np.random.default_rng(5)
    lam = np.zeros((60, 100))
    lam[:, 1::2] = 1e4                     # interleaved zeros and large means
    lam[::3, ::4] = 0.5                    # some small means among the zeros
    x = poisson(g, lam)
    assert x.shape == lam.shape and x.dtype == np.int64
    assert np.all(x[lam == 0] == 0)
    # Poisson(1e4) has sd 100; 3000 draws: all within 7 sd (P(any beyond) ~ 8e-9).
    assert np.all(np.abs(x[lam == 1e4] - 1e4) < 700)
    # Poisson(0.5) draws exceed 12 with probability ~1e-13.
    small = x[lam == 0.5]
    assert small.size == 500 and small.max() <= 12
    # Mean of 500 Poisson(0.5): sd sqrt(0.5 / 500) = 0.032; 5 sigma.
    assert abs(small.mean() - 0.5) < 5 * math.sqrt(0.5 / 500)


def test_zero_means_give_zero():
    x = poisson(np.random.default_rng(1), np.zeros(1000))
    assert np.array_equal(x, np.zeros(1000, np.int64))


def test_small_zero_is_numpy_stream():
    # With small=0 every positive mean goes to g.poisson: same stream as numpy.
    lam = np.linspace(0.01, 30.0, 5000)
    a = poisson(np.random.default_rng(9), lam, small=0.0)
    b = np.random.default_rng(9).poisson(lam)
    assert np.array_equal(a, b)


def test_deterministic():
    lam = np.random.default_rng(3).uniform(0.0, 20.0, (50, 80))
    lam[0] = 0.0
    a = poisson(np.random.default_rng(42), lam)
    b = poisson(np.random.default_rng(42), lam)
    assert np.array_equal(a, b)
    c = poisson(np.random.default_rng(43), lam)
    assert not np.array_equal(a, c)


def test_empty_and_scalar():
    g = np.random.default_rng(0)
    assert poisson(g, np.zeros((0, 3))).shape == (0, 3)
    assert poisson(g, 0.0).shape == () and poisson(g, 0.0) == 0


@pytest.mark.parametrize("bad", [-1.0, np.nan, np.inf, 1e20])
def test_bad_lam(bad):
    lam = np.full(10, 2.0)
    lam[4] = bad
    with pytest.raises(ParameterError, match="'lam'"):
        poisson(np.random.default_rng(0), lam)


@pytest.mark.parametrize("small", [-1.0, 101.0, float("nan"), True, "3"])
def test_bad_small(small):
    with pytest.raises(ParameterError, match="'small'"):
        poisson(np.random.default_rng(0), np.ones(3), small=small)


def test_bad_generator():
    with pytest.raises(ParameterError, match="'g'"):
        poisson(np.random.RandomState(0), np.ones(3))


def _chi2_pvalue(x, lam):
    """Chi-square p-value of the counts ``x`` against the Poisson(lam) pmf.

    Bins k = 0 .. K-1 and a tail bin k >= K, with K the largest k whose tail holds an
    expected count of at least 20 (so every bin expects >= 20: the chi-square law of
    the statistic holds).
    """
    n = x.size
    pmf = stats.poisson(lam)
    K = int(np.max(np.flatnonzero(n * pmf.sf(np.arange(200) - 1) >= 20)))
    obs = np.bincount(np.minimum(x, K), minlength=K + 1)
    exp = n * np.append(pmf.pmf(np.arange(K)), pmf.sf(K - 1))
    assert obs.sum() == n and K >= 1
    return stats.chisquare(obs, exp).pvalue


# Layouts of one call (4096 means): the background at a tiny mean plus
#   few:  40 means of 4.0 (at most 256 above 1: routed to g.poisson, kept in place),
#   many: 1000 means of 4.0 (more than 256 above 1: all drawn by inversion),
#   most: 3000 means of 20.0 (above `small` and more than half: the background is
#         gathered for the inversion).
_LAYOUTS = {"few": (40, 4.0), "many": (1000, 4.0), "most": (3000, 20.0)}


@pytest.mark.parametrize("layout", list(_LAYOUTS))
@pytest.mark.parametrize("lam", [1e-3, 0.025, 0.3])
def test_tiny_means_among_bright_ones(lam, layout):
    """Tiny means (the pass-0 fast path of the inversion) drawn together with brighter
    elements, as in a star on a faint background: both groups follow their Poisson
    law whichever way the bright ones are routed."""
    n_bright, lam_b = _LAYOUTS[layout]
    g = np.random.default_rng(20251121)
    pos = np.random.default_rng(1).permutation(4096)[:n_bright]   # scattered
    means = np.full(4096, lam)
    means[pos] = lam_b
    bright = np.zeros(4096, bool)
    bright[pos] = True
    calls = 100
    x = np.stack([poisson(g, means) for _ in range(calls)])
    bg, br = x[:, ~bright].ravel(), x[:, bright].ravel()
    for v, mu in ((bg, lam), (br, lam_b)):
        n = v.size
        # 5 sigma of the sample mean (sd sqrt(mu / n)) and variance
        # (sd sqrt((mu + 2 mu^2) / n)), as in test_mean_and_variance
        assert abs(v.mean() - mu) < 5 * math.sqrt(mu / n)
        assert abs(v.var(ddof=1) - mu) < 5 * math.sqrt((mu + 2 * mu ** 2) / n)
        # Fixed seed; a correct sampler fails with probability 1e-4 per check.
        assert _chi2_pvalue(v, mu) > 1e-4


def test_tiny_mean_two_plus_counts():
    """At lam = 1e-3 the chi-square above sees only k = 0 and k >= 1; check k >= 2
    separately: 2e6 draws expect N P(X >= 2) = 0.999 such counts (Poisson), so at
    most 8 (P(more) = 1e-6), and the k = 1 count within 5 sigma of N p_1 (a
    binomial count: sd <= sqrt(N p_1))."""
    g = np.random.default_rng(4)
    lam, n = 1e-3, 2_000_000
    x = np.concatenate([poisson(g, np.full(n // 10, lam)) for _ in range(10)])
    p1, p2 = stats.poisson(lam).pmf(1), stats.poisson(lam).sf(1)
    assert np.count_nonzero(x >= 2) <= 8 and stats.poisson(n * p2).sf(8) < 2e-6
    assert abs(np.count_nonzero(x == 1) - n * p1) < 5 * math.sqrt(n * p1)


def test_routing_keeps_values_in_place():
    """Bright means routed to g.poisson land at their own positions: with means of
    1e4 and 0 interleaved among a tiny background, every draw is near its own mean."""
    g = np.random.default_rng(8)
    means = np.full(5000, 0.025)
    means[7::61] = 1e4                                  # 82 elements: routed
    means[3::61] = 0.0
    for _ in range(20):
        x = poisson(g, means)
        # Poisson(1e4): sd 100; 7 sd bounds every one of 1640 draws (P ~ 2e-9)
        assert np.all(np.abs(x[7::61] - 1e4) < 700)
        assert np.all(x[3::61] == 0)
        # Poisson(0.025) exceeds 6 with probability ~2e-15 per draw
        assert x[means == 0.025].max() <= 6


@pytest.mark.parametrize("lam", [1e-3, 0.025, 1.0, 3.0, 10.0, 100.0])
def test_guide_table_is_the_inverse_cdf(lam):
    """Every bucket [b, b+1)/M of the uniform either maps to the one k that the exact
    inverse CDF (scipy) gives at both of its ends, or is marked as straddling."""
    guide, cdf = guide_table(lam)
    m = 1 << GUIDE_BITS
    exact = stats.poisson(lam).cdf(np.arange(cdf.size))
    np.testing.assert_allclose(cdf, exact, rtol=0, atol=1e-14)
    lo = np.searchsorted(exact, np.arange(m) / m, side="right")
    hi = np.searchsorted(exact, (np.arange(m) + 1) / m - 1e-15, side="right")
    pure = guide != 255
    np.testing.assert_array_equal(guide[pure], lo[pure])
    assert np.all(lo[pure] == hi[pure])
    # straddling buckets are few: at most one per CDF step inside (0, 1)
    assert np.count_nonzero(~pure) <= cdf.size


@pytest.mark.parametrize("n_others", [2000, 2 * OTHERS_NUMPY_BELOW])
def test_shared_mean_among_others_and_zero_background(n_others):
    """A dominant mean (background) with scattered others: each group follows its own
    law; a dominant mean of 0 gives exact zeros (no draws needed).  The others are
    fewer than OTHERS_NUMPY_BELOW (drawn by g.poisson in one call) or more (by the
    rules of poisson, recursively)."""
    g = np.random.default_rng(31)
    n = max(8192, 4 * n_others)
    means = np.full(n, 2.0)
    pos = np.random.default_rng(2).permutation(n)[:n_others]
    means[pos[:n_others // 2]] = 0.0
    means[pos[n_others // 2:]] = 50.0
    x = np.stack([poisson(g, means) for _ in range(50)])
    for mu, sel in ((2.0, means == 2.0), (50.0, means == 50.0)):
        v = x[:, sel].ravel()
        # 5 sigma of the sample mean and variance, as in test_mean_and_variance
        assert abs(v.mean() - mu) < 5 * math.sqrt(mu / v.size)
        assert abs(v.var(ddof=1) - mu) < 5 * math.sqrt((mu + 2 * mu ** 2) / v.size)
    assert not x[:, means == 0.0].any()
    zero_bg = np.zeros(n)
    zero_bg[::100] = 5.0
    y = poisson(g, zero_bg)
    assert not y[zero_bg == 0].any()


def test_small_arrays_are_numpy_stream():
    """Fewer than NUMPY_BELOW means: g.poisson whole (faster there); at the threshold
    the search takes over (a different stream)."""
    lam = np.linspace(0.01, 5.0, NUMPY_BELOW - 1)
    a = poisson(np.random.default_rng(11), lam)
    np.testing.assert_array_equal(a, np.random.default_rng(11).poisson(lam))
    lam = np.linspace(0.01, 5.0, NUMPY_BELOW)
    assert not np.array_equal(poisson(np.random.default_rng(11), lam),
                              np.random.default_rng(11).poisson(lam))
