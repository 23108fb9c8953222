"""Pooling over realisations, against the statistics of the concatenated pixels and
the textbook standard errors (no dask needed)."""

import math

import numpy as np
import pytest

from scenesim.batch.pool import format_pooled, jackknife, pool_reports


def _reports(z_by_real, chi=None):
    """Per-realisation reports of one bin from the z values of its pixels."""
    reps = []
    for k, z in enumerate(z_by_real):
        row = {"lo": 1.0, "hi": 10.0, "n_regular": z.size, "n": z.size,
               "bias_opt": float(z.mean()), "std_opt": float(z.std(ddof=1)),
               "std_eff": float(0.5 * z.std(ddof=1)),
               "chi2_rep": float(np.mean(z ** 2)), "bias_rep": float(z.mean()),
               "ols_ratio": 1.2, "chi2_fit": 1.0, "frac_flagged": 0.0}
        reps.append({"rows": [row], "jumps": {"n_hit": 10, "completeness": 0.9,
                                              "n_clean": 1000,
                                              "false_positive": 0.001 * (k % 2)},
                     "photometry": {"median_ratio": 1.0 + 0.01 * k}})
    return reps


def test_pooled_values_equal_those_of_all_pixels():
    g = np.random.default_rng(1)
    z = [g.normal(0.1, 1.0, n) for n in (500, 800, 650, 700)]
    row = pool_reports(_reports(z))["rows"][0]
    allz = np.concatenate(z)
    assert row["bias"] == pytest.approx(allz.mean(), rel=1e-12)
    assert row["scatter"] == pytest.approx(allz.std(ddof=1), rel=1e-12)
    assert row["chi2"] == pytest.approx(np.mean(allz ** 2), rel=1e-12)
    assert row["n_real"] == 4 and row["n_pix"] == pytest.approx(allz.size / 4)
    assert row["ols_ratio"] == pytest.approx(1.2)
    # within realisations: each about its own mean
    within = math.sqrt(sum(np.sum((x - x.mean()) ** 2) for x in z) /
                       sum(x.size - 1 for x in z))
    assert row["scatter_within"] == pytest.approx(within, rel=1e-12)
    assert row["scatter_eff"] == pytest.approx(0.5 * within, rel=1e-12)


def test_bias_error_is_the_spread_across_realisations():
    """Equal pixel counts: the jackknife error of the pooled mean is exactly
    std_k(bias_k) / sqrt(K).  With a common offset per realisation (correlated noise)
    it is far above the pixel-count error scatter / sqrt(N)."""
    g = np.random.default_rng(2)
    K, n = 40, 400
    z = [g.normal(g.normal(0, 0.3), 1.0, n) for _ in range(K)]
    row = pool_reports(_reports(z))["rows"][0]
    b = np.array([x.mean() for x in z])
    assert row["bias_se"] == pytest.approx(b.std(ddof=1) / math.sqrt(K), rel=1e-9)
    assert row["bias_se"] > 5 * row["bias_se_pixels"]


def test_bias_error_covers_the_truth_at_the_stated_rate():
    """Over 400 batches of 20 realisations, |pooled bias| / SE < 2 in about 95 % (the
    jackknife t has 19 degrees of freedom: 94 %); binomial sigma 1.2 %, bounds 5 sigma."""
    g = np.random.default_rng(3)
    inside = 0
    trials = 400
    for _ in range(trials):
        z = [g.normal(g.normal(0, 0.2), 1.0, 50) for _ in range(20)]
        row = pool_reports(_reports(z))["rows"][0]
        inside += abs(row["bias"]) < 2 * row["bias_se"]
    assert 0.88 < inside / trials < 1.0


def test_jumps_photometry_and_empty_bins():
    g = np.random.default_rng(4)
    reps = _reports([g.normal(0, 1, 10) for _ in range(4)])
    reps[0]["rows"].append({"lo": 10.0, "hi": float("inf"), "n_regular": 0, "n": 0})
    for r in reps[1:]:
        r["rows"].append({"lo": 10.0, "hi": float("inf"), "n_regular": 0, "n": 0})
    pooled = pool_reports(reps)
    j = pooled["jumps"]
    assert j["completeness"] == pytest.approx(0.9) and j["n_hit"] == 40
    assert j["false_positive"] == pytest.approx(0.0005) and j["n_clean"] == 4000
    assert pooled["photometry"]["median_ratio"] == pytest.approx(1.015)
    empty = pooled["rows"][1]
    assert empty["n_real"] == 0 and math.isnan(empty["bias"])
    text = format_pooled(pooled, title="t")
    # every realisation's completeness is 0.9: the jackknife is 0, the error is the
    # binomial one of 36 of 40 hits, p = 36.5 / 41: sqrt(p (1 - p) / 40) = 0.0494
    assert "completeness 0.9000 +- 0.0494" in text and "10 - inf" in text
    # at the boundary (all hits flagged) too: 1.0000, not +- 0.0000
    for r in reps:
        r["jumps"]["completeness"] = 1.0
    j = pool_reports(reps)["jumps"]
    p = 40.5 / 41
    assert j["completeness"] == 1.0
    assert j["completeness_se"] == pytest.approx(math.sqrt(p * (1 - p) / 40))


def test_jackknife_of_a_mean_and_of_one_realisation():
    x = np.array([1.0, 2.0, 4.0, 7.0])
    n = np.ones(4)
    value, se = jackknife(lambda a, b: b / a, n, x)
    assert value == pytest.approx(3.5)
    assert se == pytest.approx(x.std(ddof=1) / 2)
    value, se = jackknife(lambda a, b: b / a, n[:1], x[:1])
    assert value == 1.0 and math.isnan(se)
