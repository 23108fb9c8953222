"""The comparison's statistics against closed forms: usable ramps of saturated pixels,
the effective-noise optimum (measured read noise, ADC rounding), the cluster-robust
standard error of a bin's bias, and the jump threshold at a pixel's rate."""

import math

import numpy as np
import pytest
from astropy.table import Table

from scenesim.detector.dq import JUMP_DET
from scenesim.validate.compare import compare
from scenesim.validate.jumps import jump_stats
from scenesim.validate.stats import (bias_p_value, cluster_dof, cluster_se,
                                     usable_variance)

TF, NG = 10.0, 6
TIMES = [np.array([(k + 1) * TF]) for k in range(NG)]     # RAPID: single reads


def _v_white(sigma, n):
    """Least-squares slope variance of n single reads (rate 0): the GLS one there."""
    return 12 * sigma ** 2 / (TF ** 2 * n * (n ** 2 - 1))


def _header(rdnoise, gain=2.0, nints=1):
    return {"NINTS": nints, "NGROUPS": NG, "NFRAMES": 1, "GROUPGAP": 0, "DROPFRM1": 0,
            "TFRAME": TF, "READPATT": "RAPID", "RESETMD": "rolling",
            "RDNOISE": rdnoise, "GAIN": gain}


def test_usable_variance_of_saturated_pixels_is_that_of_their_first_resultants():
    sigma = 8.0
    rate = np.zeros((2, 3))
    sat = np.array([[-1, 3, 4], [2, 1, 0]])[None]        # SATGROUP, one integration
    v = usable_variance(rate, TIMES, sigma, nints=1, satgroup=sat)
    want = np.array([[_v_white(sigma, NG), _v_white(sigma, 3), _v_white(sigma, 4)],
                     [_v_white(sigma, 2), np.inf, np.inf]])
    np.testing.assert_allclose(v, want, rtol=1e-12)
    # two integrations, one cut at 3: inverse variances add
    sat2 = np.stack([np.full((2, 3), -1), np.full((2, 3), 3)])
    v2 = usable_variance(rate, TIMES, sigma, nints=2, satgroup=sat2)
    np.testing.assert_allclose(v2, 1 / (1 / _v_white(sigma, NG) + 1 / _v_white(sigma, 3)))


def _fit(slope, var, rn=None):
    shape = slope.shape
    return {"slope": slope, "var": var, "dq": np.zeros(shape, np.uint32),
            "chi2": None, "read_noise": rn}


def test_std_opt_judges_saturated_pixels_on_their_usable_ramp():
    # Synthetic fit: slopes scattered by exactly the optimum of the usable ramp
    # (3 of 6 resultants for half the pixels).  Old behaviour: the optimum of all 6
    # resultants, so std_opt = sqrt(V_3 / V_6) = 3.74 for those; new: 1.
    rng = np.random.default_rng(3)
    sigma, shape = 6.0, (100, 100)
    rate = np.zeros(shape)
    sat = np.where(np.arange(100)[None, :] < 50, 3, -1) * np.ones(shape, int)
    v = np.where(sat >= 0, _v_white(sigma, 3), _v_white(sigma, NG))
    slope = rng.standard_normal(shape) * np.sqrt(v)
    truth = {"header": _header(sigma), "RATE_IPC": rate, "SATGROUP": sat[None]}
    row = compare(_fit(slope, v, rn=sigma), truth, read_times=TIMES).rows[0]
    n = row["n"]
    # sample std of n unit normals: standard error 1/sqrt(2n); 5 sigma
    assert abs(row["std_opt"] - 1) < 5 / math.sqrt(2 * n)


def test_std_eff_uses_measured_read_noise_and_adc_rounding():
    # Groups of 4 reads, gain 3 e-/DN: each resultant carries the rounding of its
    # on-board mean, q = g^2/12 (1 - 1/16); the fit measured 7 e- per read (the model
    # says 5).  Slopes scattered by exactly that optimum: std_eff = 1, std_opt > 1.
    rng = np.random.default_rng(4)
    gain, rn_model, rn_meas = 3.0, 5.0, 7.0
    times = [TF * (4 * g + np.arange(1, 5)) for g in range(NG)]
    shape = (120, 120)
    rate = np.zeros(shape)
    q = gain / math.sqrt(12) * math.sqrt(1 - 1 / 16)
    # closed form for rate 0: resultants of variance s2 = rn^2/4 + q^2 at equally
    # spaced times 4 TF apart -> least squares 12 s2 / ((4 TF)^2 n (n^2 - 1))
    v_eff = 12 * (rn_meas ** 2 / 4 + q ** 2) / ((4 * TF) ** 2 * NG * (NG ** 2 - 1))
    slope = rng.standard_normal(shape) * math.sqrt(v_eff)
    truth = {"header": _header(rn_model, gain=gain), "RATE_IPC": rate}
    row = compare(_fit(slope, np.full(shape, v_eff), rn=rn_meas), truth,
                  read_times=times).rows[0]
    n = row["n"]
    assert abs(row["std_eff"] - 1) < 5 / math.sqrt(2 * n)          # 5 sigma
    v_opt = 12 * (rn_model ** 2 / 4) / ((4 * TF) ** 2 * NG * (NG ** 2 - 1))
    assert row["std_opt"] == pytest.approx(math.sqrt(v_eff / v_opt), rel=0.03)


def test_cluster_se_matches_the_variance_of_a_clustered_mean():
    # z = c_b + e_p with B clusters of m pixels: Var(mean) = s_c^2 / B + s_e^2 / n.
    # Over 400 repetitions the reported SE (mean of squares) must match the actual
    # spread of the mean: 5 sigma of a variance estimated from 400 draws is ~35 %.
    rng = np.random.default_rng(5)
    B, m, s_c, s_e = 40, 50, 0.3, 1.0
    labels = np.repeat(np.arange(B), m)
    means, se2 = [], []
    for _ in range(400):
        z = np.repeat(rng.normal(0, s_c, B), m) + rng.normal(0, s_e, B * m)
        means.append(z.mean())
        se2.append(cluster_se(z, labels) ** 2)
    want = s_c ** 2 / B + s_e ** 2 / (B * m)
    assert np.var(means) == pytest.approx(want, rel=0.35)
    assert np.mean(se2) == pytest.approx(want, rel=0.1)
    # one pixel per cluster: the usual standard error
    z = rng.normal(size=1000)
    assert cluster_se(z, np.arange(1000)) == pytest.approx(z.std(ddof=1) / math.sqrt(1000),
                                                           rel=1e-3)


def test_a_bias_from_few_unequal_clusters_is_judged_by_student_t():
    # A bin of a few stars holds a few clusters of unequal sizes (a probe: 3-7 in
    # the quick scene's star bins, where |bias / se| > 3 came 13-40 times as often
    # as a normal law says).  For independent N(0, 1) values: the CR2 variance is
    # unbiased whatever the sizes (mean of se^2 vs 1/n: 4000 draws of a variance
    # estimate with ~4 degrees of freedom, relative SE sqrt(2/4/4000) = 1.1 %, 5
    # sigma 6 %), and p_bias < alpha comes at most alpha of the time (Satterthwaite
    # degrees of freedom: conservative for unequal sizes; binomial SE of a rate of
    # 0.05 over 4000 draws is 0.0034, 5 sigma 0.017).  Equal clusters: B - 1 dof.
    rng = np.random.default_rng(11)
    sizes = [30, 20, 10, 10, 5]
    labels = np.repeat(np.arange(len(sizes)), sizes)
    n = labels.size
    dof = cluster_dof(labels)
    assert 1.0 < dof < len(sizes) - 1
    se2, p = [], []
    for _ in range(4000):
        z = rng.standard_normal(n)
        se = cluster_se(z, labels)
        se2.append(se ** 2)
        p.append(bias_p_value(z.mean(), se, dof))
    assert np.mean(se2) * n == pytest.approx(1.0, abs=0.06)
    p = np.array(p)
    assert np.mean(p < 0.05) < 0.05 + 0.017
    assert np.mean(p < 0.01) < 0.01 + 5 * math.sqrt(0.01 * 0.99 / 4000)
    assert cluster_dof(np.repeat(np.arange(7), 12)) == pytest.approx(6.0, rel=1e-12)
    assert math.isnan(bias_p_value(0.1, 0.0, 4.0))
    # nearly one cluster (a star's band and two stray pixels): no calibrated test
    assert cluster_dof(np.repeat(np.arange(3), [100, 1, 1])) < 2
    assert math.isnan(bias_p_value(0.5, 0.1, 1.02))


def test_jump_hit_threshold_includes_the_pixels_shot_noise():
    # A 300 e- deposit on a dark pixel (10 sigma = 10 sqrt(2) 5 = 70.7 e-) is a hit;
    # on a pixel at 1e4 e-/s with t_frame 10 s (difference noise sqrt(50 + 1e5) =
    # 316 e-, 10 sigma = 3.2e3 e-) it is not (old rule: read noise alone made it a
    # hit that no method could see).
    shape = (4, 4)
    rate = np.zeros(shape)
    rate[2, 2] = 1e4
    crs = Table({"X": [1, 2], "Y": [1, 2], "CHARGE": [300.0, 300.0],
                 "SEEN": [True, True], "TIME": [1.0, 1.0]})
    dq = np.zeros(shape, np.uint32)
    dq[1, 1] = JUMP_DET
    regular = np.ones(shape, bool)
    j = jump_stats(dq, crs, shape, 5.0, 10.0, regular, rate=rate, t_read=TF)
    assert j["n_hit"] == 1 and j["completeness"] == 1.0
    old = jump_stats(dq, crs, shape, 5.0, 10.0, regular)
    assert old["n_hit"] == 2
