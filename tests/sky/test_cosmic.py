"""Tests of scenesim.sky.cosmic: Poisson counts, uniform times, charge bookkeeping."""

import math
import pickle

import numpy as np
import pytest

from noise.errors import ParameterError
from scenesim.sky.cosmic import CosmicRayModel, draw_cosmic_rays


def test_event_count_mean_and_variance_are_poisson():
    model = CosmicRayModel(rate=5.0)
    shape, pitch, duration = (20, 20), 18.0, 4000.0
    lam = 5.0 * 20 * 20 * (18e-4) ** 2 * duration        # 1.296e-3 cm^2 -> 25.92 hits
    seeds = np.random.SeedSequence(401).spawn(400)
    counts = np.array([draw_cosmic_rays(model, shape, pitch, 0.0, duration,
                                        rng=s).meta["NEVENTS"] for s in seeds])
    m = counts.size
    # sample mean: sigma = sqrt(lam / m); sample variance: for a Poisson law
    # mu4 = lam + 3 lam^2, so Var(s^2) ~ (mu4 - lam^2)/m = (lam + 2 lam^2)/m
    assert abs(counts.mean() - lam) <= 5 * math.sqrt(lam / m)
    assert abs(counts.var(ddof=1) - lam) <= 5 * math.sqrt((lam + 2 * lam ** 2) / m)


def test_hit_times_uniform_and_sorted():
    model = CosmicRayModel(rate=50.0, charge_sigma=0.0)
    t0, t1 = 100.0, 1100.0
    tab = draw_cosmic_rays(model, (64, 64), 18.0, t0, t1, rng=402)
    n = tab.meta["NEVENTS"]
    assert n > 500                  # expected 50 /cm^2/s * 0.01327 cm^2 * 1000 s = 663
    ev, first = np.unique(np.asarray(tab["EVENT"]), return_index=True)
    times = np.asarray(tab["TIME"])[first]
    assert ev.size == n             # every hit leaves charge (no refmask, 3x3 kernel)
    assert np.all(np.diff(np.asarray(tab["TIME"])) >= 0)
    assert times.min() >= t0 and times.max() < t1
    # binned chi^2 with k = 20 equal bins: under uniformity chi^2 ~ chi^2(19),
    # mean 19 and sd sqrt(38); accept below mean + 5 sd
    k = 20
    obs = np.histogram(times, bins=k, range=(t0, t1))[0]
    chi2 = ((obs - n / k) ** 2 / (n / k)).sum()
    assert chi2 <= (k - 1) + 5 * math.sqrt(2 * (k - 1))


def test_charge_conserved_and_split_follows_footprint():
    q = 5000.0
    model = CosmicRayModel(rate=5.0, charge_mean=q, charge_sigma=0.0)
    tab = draw_cosmic_rays(model, (40, 40), 18.0, 0.0, 3000.0, rng=403)
    n = tab.meta["NEVENTS"]
    # whole-electron bookkeeping: deposits + charge off the array = n * q exactly
    assert int(np.sum(tab["CHARGE"])) + tab.meta["QOFFARR"] == n * int(q)
    assert tab.meta["QREFPIX"] == 0
    ev = np.asarray(tab["EVENT"])
    sums = np.bincount(ev, weights=np.asarray(tab["CHARGE"]), minlength=n)
    counts = np.bincount(ev, minlength=n)
    full = counts == 9              # hit at least one pixel from every edge
    assert np.all(sums[full] == q) and np.all(sums <= q)
    # mean split: over E complete events the charge at kernel offset j is
    # Binomial(E q, p_j); compare with 5 sigma = 5 sqrt(E q p (1 - p))
    sel = full[ev]
    x, y, c = (np.asarray(tab[k])[sel] for k in ("X", "Y", "CHARGE"))
    e = ev[sel]
    cx = np.repeat(np.bincount(e, weights=x)[full] / 9, 9)   # centre = mean position
    cy = np.repeat(np.bincount(e, weights=y)[full] / 9, 9)
    dx = np.rint(x - cx).astype(int) + 1
    dy = np.rint(y - cy).astype(int) + 1
    total = np.zeros((3, 3))
    np.add.at(total, (dy, dx), c)
    n_full = int(full.sum())
    kern = np.asarray(model.footprint)
    sigma = np.sqrt(n_full * q * kern * (1 - kern))
    assert np.all(np.abs(total - n_full * q * kern) <= 5 * sigma)


def test_no_deposits_on_reference_pixels():
    ref = np.zeros((32, 32), bool)
    ref[:4] = ref[-4:] = True
    ref[:, :4] = ref[:, -4:] = True
    model = CosmicRayModel(rate=20.0, charge_mean=3000.0, charge_sigma=0.0)
    tab = draw_cosmic_rays(model, (32, 32), 18.0, 0.0, 2000.0, rng=404, refmask=ref)
    x, y = np.asarray(tab["X"]), np.asarray(tab["Y"])
    assert len(tab) > 0 and not ref[y, x].any()
    assert tab.meta["QREFPIX"] > 0
    assert (int(np.sum(tab["CHARGE"])) + tab.meta["QOFFARR"] + tab.meta["QREFPIX"]
            == tab.meta["NEVENTS"] * 3000)


def test_lognormal_and_table_charge_distributions():
    model = CosmicRayModel(charge_mean=4000.0, charge_sigma=3000.0)
    q = model.draw_charge(40000, rng=405).astype(float)
    s2 = math.log1p((3000 / 4000) ** 2)
    mu = math.log(4000) - s2 / 2
    # ln q ~ N(mu, s2) (rounding to whole e- shifts ln q by < 0.5/q ~ 1e-3 at the
    # low tail, far below the 5 sigma = 5 sqrt(s2/n) = 0.017 band)
    lq = np.log(q)
    n = q.size
    assert abs(lq.mean() - mu) <= 5 * math.sqrt(s2 / n)
    # sample variance of a normal: sd 5 * s2 * sqrt(2/(n-1))
    assert abs(lq.var(ddof=1) - s2) <= 5 * s2 * math.sqrt(2 / (n - 1))
    tmodel = CosmicRayModel(charge_distribution="table",
                            charge_edges=(0.0, 1000.0, 2000.0, 5000.0),
                            charge_weights=(1.0, 2.0, 1.0))
    qt = tmodel.draw_charge(20000, rng=406)
    obs = np.histogram(qt, bins=[-0.5, 999.5, 1999.5, 5000.5])[0]
    p = np.array([0.25, 0.5, 0.25])
    # multinomial counts: each within 5 sqrt(n p (1 - p))
    assert np.all(np.abs(obs - qt.size * p) <= 5 * np.sqrt(qt.size * p * (1 - p)))


def test_null_cases_and_seeding():
    model = CosmicRayModel(rate=0.0)
    tab = draw_cosmic_rays(model, (16, 16), 18.0, 0.0, 1e4, rng=407)
    assert len(tab) == 0 and tab.meta["NEVENTS"] == 0
    tab = draw_cosmic_rays(CosmicRayModel(), (16, 16), 18.0, 5.0, 5.0, rng=408)
    assert len(tab) == 0
    a = draw_cosmic_rays(CosmicRayModel(), (16, 16), 18.0, 0.0, 1e3, rng=409)
    b = draw_cosmic_rays(CosmicRayModel(), (16, 16), 18.0, 0.0, 1e3, rng=409)
    assert len(a) > 0 and all(np.array_equal(a[c], b[c]) for c in a.colnames)


def test_model_validation_and_value_semantics():
    m = CosmicRayModel()
    assert pickle.loads(pickle.dumps(m)) == m and hash(m) == hash(CosmicRayModel())
    with pytest.raises(ParameterError, match="rate"):
        CosmicRayModel(rate=-1.0)
    with pytest.raises(ParameterError, match="footprint"):
        CosmicRayModel(footprint=((0.5, 0.5),))
    with pytest.raises(ParameterError, match="sum to 1"):
        CosmicRayModel(footprint=((0.0, 0.1, 0.0), (0.1, 0.5, 0.1), (0.0, 0.1, 0.0)))
    with pytest.raises(ParameterError, match="charge_edges"):
        CosmicRayModel(charge_distribution="table")
    with pytest.raises(ParameterError, match="only used"):
        CosmicRayModel(charge_edges=(0.0, 1.0), charge_weights=(1.0,))
    with pytest.raises(ParameterError, match="charge_distribution"):
        CosmicRayModel(charge_distribution="landau")
    with pytest.raises(ParameterError, match="t_stop"):
        draw_cosmic_rays(m, (8, 8), 18.0, 10.0, 5.0, rng=0)
    with pytest.raises(ParameterError, match="pixel_pitch_um"):
        draw_cosmic_rays(m, (8, 8), 0.0, 0.0, 5.0, rng=0)
    with pytest.raises(ParameterError, match="refmask"):
        draw_cosmic_rays(m, (8, 8), 18.0, 0.0, 5.0, rng=0, refmask=np.zeros((4, 4)))
