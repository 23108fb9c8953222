"""Tests of :mod:`scenesim.engine` against closed forms.

Charge between reads is Poisson with mean ``integral rate dt`` over each pixel's own
interval; read times follow ``docs/CONVENTIONS.md`` (slot * t_frame + t_pix); global
reset integrates ``k * t_frame + t_pix`` to read ``k``; cosmic rays appear in the first
read after their time; saturation happens at the first read whose charge reaches the
full well; resultants average the reads listed by the readout.  Expected values are
computed here from those formulas, not from the engine.
"""

import numpy as np
import pytest

from noise.clock import Detector, preset
from noise.errors import ParameterError
from scenesim.engine import ChargeEngine, CosmicRayHits, EngineOptions, VariableSource
from scenesim.run import write_exposure
from scenesim.sky.lightcurve import LightCurve
from scenesim.detector.readout import Readout


def _det():
    """64x64 H2RG: 4 outputs of 16 columns, nroh=12, nfoh=1, dt=1e-5 s.

    t_frame = (64 + 1) * (16 + 12) * 1e-5 s = 0.0182 s (closed form, Rauscher 2015).
    """
    return preset("H2RG", naxis1=64, naxis2=64)


T_FRAME = 65 * 28 * 1e-5


def _collect(engine):
    """Run ``engine`` and return (charge (nints, ngroups, ny, nx) float64, run output)."""
    ro = engine.readout
    det = engine.detector
    charge = np.zeros((ro.nints, ro.ngroups) + det.shape)

    with engine.simulate(save_charge=True) as run:
        for res in run:
            charge[res.integration, res.index] = res.charge
    return charge, {"sat_read": run.sat_read, "cr_seen": run.cr_seen}


def test_frame_time_matches_closed_form():
    assert _det().frame_time == pytest.approx(T_FRAME, rel=1e-12)


@pytest.mark.parametrize("lam", [1e-3, 0.1, 10.0, 1e3, 1e5])
def test_poisson_increments(lam):
    """Increments between consecutive reads (rolling reset: all last t_frame) are
    integers with mean and variance ``lam = rate * t_frame``."""
    det = _det()
    nreads = 40 if lam < 1 else 2
    ro = Readout.from_reads([[k] for k in range(nreads)])
    eng = ChargeEngine(det, ro, rate=lam / det.frame_time, rng=12345)
    charge, _ = _collect(eng)
    reg = ~det.reference_mask()
    cum = charge[0][:, reg]                                  # (nreads, npix)
    inc = np.diff(np.concatenate([np.zeros((1, cum.shape[1])), cum]), axis=0).ravel()
    assert np.all(inc == np.rint(inc))
    assert np.all(inc >= 0)
    n = inc.size
    # sample mean of n iid Poisson(lam): sd sqrt(lam / n); 5 sigma
    assert abs(inc.mean() - lam) < 5 * np.sqrt(lam / n)
    # sample variance: Var(s^2) = mu4/n - (n-3)/(n(n-1)) sigma^4 with Poisson
    # mu4 = lam + 3 lam^2, i.e. ~ (2 lam^2 + lam) / n; 5 sigma
    assert abs(inc.var(ddof=1) - lam) < 5 * np.sqrt((2 * lam ** 2 + lam) / n)
    # reference pixels collect nothing
    assert np.all(charge[0][:, ~reg] == 0)


def test_gauss_above_matches_moments():
    """The Gaussian approximation keeps mean and variance lam (integers, >= 0)."""
    det = _det()
    lam = 400.0
    ro = Readout.from_reads([[0]])
    eng = ChargeEngine(det, ro, rate=lam / det.frame_time, rng=7,
                       options=EngineOptions(gauss_above=100.0))
    charge, _ = _collect(eng)
    x = charge[0, 0][~det.reference_mask()]
    n = x.size
    assert np.all(x == np.rint(x))
    # 5 sigma of the sample mean and variance (see test_poisson_increments)
    assert abs(x.mean() - lam) < 5 * np.sqrt(lam / n)
    assert abs(x.var(ddof=1) - lam) < 5 * np.sqrt((2 * lam ** 2 + lam) / n)


def test_arrivals_2d_shortcut_moments_and_shape():
    """'2d' shortcut: the last read is Poisson(lam_total) and every read is the same
    draw scaled by its expected fraction, (k + 1) / n for rolling reset."""
    det = _det()
    nreads, lam = 5, 50.0                                   # lam per read interval
    ro = Readout.from_reads([[k] for k in range(nreads)])
    eng = ChargeEngine(det, ro, rate=lam / det.frame_time, rng=11,
                       options=EngineOptions(arrivals="2d"))
    charge, _ = _collect(eng)
    reg = ~det.reference_mask()
    last = charge[0, -1][reg]
    n = last.size
    lam_tot = nreads * lam
    assert np.all(np.abs(last - np.rint(last)) < 1e-3)     # whole electrons (float32)
    # 5 sigma of the sample mean / variance of Poisson(lam_tot), as in
    # test_poisson_increments
    assert abs(last.mean() - lam_tot) < 5 * np.sqrt(lam_tot / n)
    assert abs(last.var(ddof=1) - lam_tot) < 5 * np.sqrt((2 * lam_tot ** 2 + lam_tot) / n)
    for k in range(nreads):                                 # deterministic fractions
        np.testing.assert_allclose(charge[0, k][reg], last * (k + 1) / nreads,
                                   rtol=1e-6, atol=1e-3)
    with pytest.raises(ParameterError, match="'arrivals'.*'time', '2d'.*'3d'"):
        EngineOptions(arrivals="3d")
    with pytest.raises(ParameterError, match="gauss_above"):
        EngineOptions(gauss_above=-1.0)


def test_no_charge_noise_only_ramp():
    """Rate 0 everywhere: the engine adds the noise alone.  With white read noise
    sigma and a large bias, a read's DN (gain 1) is bias + N(0, sigma^2) rounded."""
    import noise
    det = _det()
    params = noise.ZERO_NOISE.replace(rd_noise=5.0, bias_offset=1000.0)
    eng = ChargeEngine(det, Readout.from_reads([[0], [1]]), noise_params=params, rng=2)
    dn = {}
    for res in eng.simulate():
        dn[res.index] = res.dn.astype(float)
    x = dn[1][~det.reference_mask()] - dn[0][~det.reference_mask()]
    n = x.size
    # CDS of two reads: variance 2 sigma^2 + 2/12 (rounding); 5 sigma of the mean
    # (sd sqrt(var / n)) and of the sample variance (sd var sqrt(2 / n))
    var = 2 * 25.0 + 2 / 12
    assert abs(x.mean()) < 5 * np.sqrt(var / n)
    assert abs(x.var() - var) < 5 * var * np.sqrt(2 / n)
    assert abs(dn[0].mean() - 1000) < 5 * np.sqrt(25.0 / dn[0].size) + 0.5


def test_per_pixel_time_step_source():
    """A source switching on at T (mid read frame 2) shows in read 2 exactly in the
    pixels read after T, and in every regular pixel from read 3 on."""
    det = _det()
    ro = Readout.from_reads([[0], [1], [2], [3]])
    tf = det.frame_time
    tpix = det.pixel_time()
    # read 2 is in absolute slot 3; T half a pixel time after sample 900 of that frame
    t_in = (900 + 0.5) * det.dt
    T = 3 * tf + t_in
    reg = ~det.reference_mask()
    idx = np.flatnonzero(reg)
    # weight 1e7 e-/s: a pixel read 0.5 dt = 5 us after T has lam = 50, P(0) = e^-50
    src = VariableSource(idx, np.full(idx.size, 1e7), LightCurve.step(T, before=0.0, after=1.0))
    eng = ChargeEngine(det, ro, variable_sources=[src], rng=3)
    charge, _ = _collect(eng)
    c = charge[0]
    assert np.all(c[0] == 0) and np.all(c[1] == 0)
    after = (tpix > t_in) & reg
    assert 0 < after.sum() < reg.sum()
    assert np.all(c[2][after] > 0)
    assert np.all(c[2][~after] == 0)
    assert np.all(c[3][reg] > 0)
    assert np.all(c[3][~reg] == 0)


def test_global_reset_first_read_exact():
    """Global reset, no shot noise: read k holds rate * (k t_frame + t_pix)."""
    det = _det()
    rate = 1000.0
    ro = Readout.from_reads([[0], [1], [2]], reset_mode="global")
    eng = ChargeEngine(det, ro, rate=rate, rng=1, options=EngineOptions(shot_noise=False))
    tpix = det.pixel_time()
    reg = ~det.reference_mask()
    out = write_exposure(eng, None)
    charge, _ = _collect(eng)
    for k in range(3):
        expect = rate * (k * det.frame_time + tpix)
        # float32 charge: relative precision 2^-24
        np.testing.assert_allclose(charge[0, k][reg], expect[reg], rtol=1e-6)
        # gain 1, one read per resultant: the ADC rounds to the nearest DN (<= 0.5)
        assert np.all(np.abs(out["sci"][0, k][reg] - expect[reg]) <= 0.5 + 1e-6)
    # rolling reset instead: every pixel integrates (k + 1) t_frame
    ro2 = Readout.from_reads([[0], [1]])
    eng2 = ChargeEngine(det, ro2, rate=rate, rng=1,
                        options=EngineOptions(shot_noise=False))
    c2, _ = _collect(eng2)
    np.testing.assert_allclose(c2[0, 0][reg], rate * det.frame_time, rtol=1e-6)


def test_global_reset_poisson_mean_by_row():
    """With shot noise the first-read charge summed over a row (pixels of similar
    t_pix) matches rate * sum(t_pix) of that row."""
    det = _det()
    rate = 2e4
    ro = Readout.from_reads([[0]], reset_mode="global")
    eng = ChargeEngine(det, ro, rate=rate, rng=11)
    charge, _ = _collect(eng)
    reg = ~det.reference_mask()
    tpix = det.pixel_time()
    got = np.where(reg, charge[0, 0], 0).sum(axis=1)
    lam = np.where(reg, rate * tpix, 0).sum(axis=1)
    rows = lam > 0
    assert rows.sum() == 56
    # a sum of independent Poisson draws is Poisson(sum lam): sd sqrt(sum lam);
    # 5 sigma per row (56 rows: family false-alarm ~ 56 * 6e-7)
    assert np.all(np.abs(got[rows] - lam[rows]) < 5 * np.sqrt(lam[rows]))
    # the row means increase with time, as they must (slope ~ rate * row_time)
    assert np.all(np.diff(lam[rows]) > 0)


def test_cosmic_ray_appears_after_its_time():
    """A deposit changes only its pixel and only the reads after its time."""
    det = _det()
    ro = Readout.from_reads([[k] for k in range(5)], nints=2)
    tf = det.frame_time
    tpix = det.pixel_time()
    p1 = (10, 20)
    p2 = (40, 50)
    nx = det.nx
    # hit 1 just after p1's read in slot 3 (read 2): first seen by read 3
    t1 = 3 * tf + tpix[p1] + 0.5 * det.dt
    # hit 2 just before p2's read in slot 2 (read 1): first seen by read 1
    t2 = 2 * tf + tpix[p2] - 0.5 * det.dt
    cr = CosmicRayHits(np.array([t1, t2]),
                       np.array([p1[0] * nx + p1[1], p2[0] * nx + p2[1]]),
                       np.array([1234.0, 567.0]))
    base = ChargeEngine(det, ro, rate=50.0, rng=99)
    hit = ChargeEngine(det, ro, rate=50.0, rng=99, cosmic_rays=cr)
    c0, _ = _collect(base)
    c1, out = _collect(hit)
    diff = c1 - c0
    expect = np.zeros_like(diff)
    expect[0, 3:, p1[0], p1[1]] = 1234.0
    expect[0, 1:, p2[0], p2[1]] = 567.0
    # integration 1 starts with a reset: the deposits are gone
    np.testing.assert_array_equal(diff, expect)
    assert out["cr_seen"].tolist() == [True, True]


def test_cosmic_ray_before_reset_unseen():
    """A deposit before the pixel's reset (rolling: slot 0 ends at t_pix) is erased."""
    det = _det()
    ro = Readout.from_reads([[0], [1]])
    p = (30, 30)
    t = det.pixel_time()[p] - 0.5 * det.dt
    cr = CosmicRayHits(np.array([t]), np.array([p[0] * det.nx + p[1]]), np.array([1e3]))
    eng = ChargeEngine(det, ro, rate=0.0, cosmic_rays=cr, rng=1)
    c, out = _collect(eng)
    assert np.all(c == 0)
    assert out["cr_seen"].tolist() == [False]


def test_saturation_read():
    """sat_read is the first read whose expected charge rate*(k+1)*t_frame reaches
    the full well; the charge then stays at the full well."""
    det = _det()
    rate = 1e4
    nreads = 6
    ro = Readout.from_reads([[k] for k in range(nreads)])
    q1 = rate * det.frame_time
    rng = np.random.default_rng(5)
    j = rng.integers(0, nreads + 2, size=det.shape)      # expected first read j
    full_well = q1 * (j + 0.5)                            # reached first at read k = j
    eng = ChargeEngine(det, ro, rate=rate, full_well=full_well, rng=2,
                       options=EngineOptions(shot_noise=False))
    c, out = _collect(eng)
    reg = ~det.reference_mask()
    expect = np.where(j < nreads, j, -1)
    np.testing.assert_array_equal(out["sat_read"][0][reg], expect[reg])
    assert np.all(out["sat_read"][0][~reg] == -1)
    k = np.arange(nreads)[:, None, None]
    ramp = np.minimum(rate * (k + 1) * det.frame_time, full_well)
    np.testing.assert_allclose(c[0][:, reg], ramp[:, reg], rtol=1e-6)


def _pattern_check(ro, rate, det):
    tf = det.frame_time
    eng = ChargeEngine(det, ro, rate=rate, rng=4, options=EngineOptions(shot_noise=False))
    sci = write_exposure(eng, None)["sci"].astype(np.float64)
    reg = ~det.reference_mask()
    for r, reads in enumerate(ro.resultants):
        tbar = tf * (np.mean(reads) + 1.0)       # rolling reset: read k at (k+1) t_frame
        # each read is rounded by the ADC (<= 0.5 DN), the average of the rounded
        # reads rounded again (<= 0.5 DN): |error| <= 1 DN
        assert np.all(np.abs(sci[0, r][reg] - rate * tbar) <= 1.0 + 1e-9), (r, reads)
        assert np.all(sci[0, r][~reg] == 0)
    return sci


def test_multiaccum_resultants():
    """NFRAMES=4, GROUPGAP=2, NSKIP=1: group g averages reads 1+6g .. 4+6g."""
    det = _det()
    ro = Readout.multiaccum(4, 3, groupgap=2, nskip=1)
    assert ro.resultants == ((1, 2, 3, 4), (7, 8, 9, 10), (13, 14, 15, 16))
    sci = _pattern_check(ro, 123.4, det)
    # charge of the skipped frames is kept: successive groups differ by 6 frames
    reg = ~det.reference_mask()
    step = 123.4 * 6 * det.frame_time
    assert np.all(np.abs(np.diff(sci[0][:, reg], axis=0) - step) <= 2.0 + 1e-9)


def test_ma_table_with_skips():
    """Uneven MA table with skipped reads: a resultant after a gap includes the charge
    collected during the skipped frames."""
    det = _det()
    ro = Readout.from_ma_table([(0, 1), (2, 2), (7, 3), (15, 1)])
    rate = 321.0
    sci = _pattern_check(ro, rate, det)
    reg = ~det.reference_mask()
    # single-read resultant 15: exactly rint(rate * 16 t_frame), reads 11-14 skipped
    np.testing.assert_array_equal(sci[0, 3][reg], np.rint(rate * 16 * det.frame_time))


def test_charge_resultant_averages_reads_exactly():
    """save_charge resultants are the mean of the per-read charges (no rounding)."""
    det = _det()
    rate = 77.7
    ro = Readout.from_ma_table([(1, 3), (6, 5)])
    eng = ChargeEngine(det, ro, rate=rate, rng=4, options=EngineOptions(shot_noise=False))
    c, _ = _collect(eng)
    reg = ~det.reference_mask()
    for r, reads in enumerate(ro.resultants):
        np.testing.assert_allclose(c[0, r][reg], rate * det.frame_time
                                   * (np.mean(reads) + 1.0), rtol=1e-6)


def test_gain_converts_electrons_to_dn():
    """DN = rint(e- / gain) for one-read resultants without noise."""
    det = _det()
    rate = 5000.0
    gain = 2.5
    ro = Readout.from_reads([[0], [3]])
    eng = ChargeEngine(det, ro, rate=rate, gain=gain, rng=1,
                       options=EngineOptions(shot_noise=False))
    sci = write_exposure(eng, None)["sci"]
    reg = ~det.reference_mask()
    for r, k in enumerate((0, 3)):
        assert np.all(np.abs(sci[0, r][reg] - rate * (k + 1) * det.frame_time / gain)
                      <= 0.5 + 1e-6)


def test_same_seed_identical_and_threads_independent():
    """Same seed -> identical SCI; threads=1 and threads=2 identical, noise on."""
    import noise
    det = preset("H2RG", naxis1=128, naxis2=64)
    ro = Readout.multiaccum(2, 3, groupgap=1)
    rate = np.random.default_rng(0).uniform(0, 500, det.shape)

    def sci(seed, threads):
        eng = ChargeEngine(det, ro, rate=rate, noise_params=noise.NoiseParams(),
                           rng=seed, options=EngineOptions(threads=threads))
        assert eng.noise is not None
        return write_exposure(eng, None)["sci"]

    a = sci(2024, 1)
    b = sci(2024, 1)
    c = sci(2024, 2)
    d = sci(2025, 2)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, c)
    assert np.mean(a != d) > 0.5


@pytest.mark.parametrize("rate", [-1.0, np.nan, np.inf])
def test_bad_rate(rate):
    det = _det()
    r = np.full(det.shape, 10.0)
    r[20, 20] = rate
    with pytest.raises(ParameterError, match="rate"):
        ChargeEngine(det, Readout.from_reads([[0]]), rate=r)


@pytest.mark.parametrize("gain", [0.0, -2.0, np.nan])
def test_bad_gain(gain):
    with pytest.raises(ParameterError, match="gain"):
        ChargeEngine(_det(), Readout.from_reads([[0]]), gain=gain)


def test_bad_full_well():
    det = _det()
    ro = Readout.from_reads([[0]])
    with pytest.raises(ParameterError, match="full_well"):
        ChargeEngine(det, ro, full_well=0.0)


def test_bad_variable_source():
    det = _det()
    ro = Readout.from_reads([[0]])
    n = det.nx * det.ny
    with pytest.raises(ParameterError, match="out of range"):
        ChargeEngine(det, ro, variable_sources=[
            VariableSource(np.array([n]), np.array([1.0]), LightCurve.step(0.0, before=0.0, after=1.0))])
    with pytest.raises(ParameterError, match="weights"):
        ChargeEngine(det, ro, variable_sources=[
            VariableSource(np.array([5]), np.array([-1.0]), LightCurve.step(0.0, before=0.0, after=1.0))])


@pytest.mark.parametrize("name", ["rate", "full_well"])
def test_bad_shape(name):
    """Per-pixel arrays of the wrong shape are rejected before any work."""
    with pytest.raises(ParameterError, match=name):
        ChargeEngine(_det(), Readout.from_reads([[0]]), **{name: np.ones((10, 10))})


@pytest.mark.parametrize("reset_mode", ["rolling", "global"])
def test_variable_source_exact_charge_two_integrations(reset_mode):
    """No shot noise: a step source in an otherwise dark region (partial row chunk)
    collects weight * (t_read - max(T, t_reset)) with absolute times
    t_read = slot * t_frame + t_pix, in both integrations."""
    det = _det()
    tf = det.frame_time
    nreads = 3
    ro = Readout.from_reads([[k] for k in range(nreads)], nints=2, reset_mode=reset_mode)
    pix = np.array([[40, 10], [50, 50], [45, 30]])
    idx = pix[:, 0] * det.nx + pix[:, 1]
    w = np.array([1e4, 2e4, 3e4])
    T = 2.3 * tf
    src = VariableSource(idx, w, LightCurve.step(T, before=0.0, after=1.0))
    eng = ChargeEngine(det, ro, variable_sources=[src], rng=0,
                       options=EngineOptions(shot_noise=False))
    c, _ = _collect(eng)
    tpix = det.pixel_time()[pix[:, 0], pix[:, 1]]
    for i in range(2):
        for k in range(nreads):
            slot = i * (1 + nreads) + 1 + k
            t_read = slot * tf + tpix
            if reset_mode == "rolling":
                t_reset = t_read - (k + 1) * tf
            else:
                t_reset = np.full(3, (i * (1 + nreads) + 1) * tf)
            expect = w * np.maximum(t_read - np.maximum(T, t_reset), 0.0)
            np.testing.assert_allclose(c[i, k][pix[:, 0], pix[:, 1]], expect, rtol=1e-6)
            others = np.ones(det.shape, bool)
            others[pix[:, 0], pix[:, 1]] = False
            assert np.all(c[i, k][others] == 0)


def test_sparse_chunk_grouped_reads_poisson_and_independent():
    """A third of the pixels charged (a sparse stream chunk, its 20 reads drawn in one
    call): increments are Poisson(lam) there and 0 elsewhere, and increments of
    consecutive reads and of the two integrations are uncorrelated."""
    det = _det()
    lam = 0.3
    nreads = 20
    yy, xx = np.mgrid[:det.ny, :det.nx]
    on = ((xx + 2 * yy) % 3 == 0) & ~det.reference_mask()
    ro = Readout.from_reads([[k] for k in range(nreads)], nints=2)
    eng = ChargeEngine(det, ro, rate=np.where(on, lam / det.frame_time, 0.0), rng=99)
    # the layout this test is about: one chunk drawing only its charged pixels, all
    # reads of an integration in one group
    layout = eng.poisson_layout
    assert len(layout["chunks"]) == 1 and layout["chunks"][0][2]       # sparse
    assert layout["reads_per_call"] >= nreads
    charge, _ = _collect(eng)
    cum = charge[:, :, on]                                   # (nints, nreads, npix)
    inc = np.diff(np.concatenate([np.zeros_like(cum[:, :1]), cum], axis=1), axis=1)
    assert np.all(charge[:, :, ~on] == 0)
    assert np.all(inc == np.rint(inc)) and np.all(inc >= 0)
    x = inc.ravel()
    n = x.size
    # 5 sigma of the sample mean and variance (see test_poisson_increments)
    assert abs(x.mean() - lam) < 5 * np.sqrt(lam / n)
    assert abs(x.var(ddof=1) - lam) < 5 * np.sqrt((2 * lam ** 2 + lam) / n)

    def corr(a, b):
        a, b = a.ravel() - a.mean(), b.ravel() - b.mean()
        return float(np.sum(a * b) / np.sqrt(np.sum(a * a) * np.sum(b * b)))

    # Pearson r of m independent pairs: sd ~ 1/sqrt(m); 5 sigma
    m = inc[:, 1:].size
    assert abs(corr(inc[:, 1:], inc[:, :-1])) < 5 / np.sqrt(m)
    m = inc[0].size
    assert abs(corr(inc[0], inc[1])) < 5 / np.sqrt(m)


@pytest.mark.parametrize("case", ["exact", "sparse", "gauss", "2d"])
def test_multichunk_results_threads_independent(case):
    """Several stream chunks on the thread pool (> 65536 charged pixels), dense or
    sparse chunks, grouped reads, a light-curve source and two integrations: the
    charge and the SCI are identical for threads=1 and threads=2."""
    det = preset("H2RG", naxis1=512, naxis2=512)
    g = np.random.default_rng(31)
    rate = g.uniform(0, 50, det.shape)
    if case == "sparse":
        rate[g.random(det.shape) > 0.4] = 0.0                # ~40 % charged
    idx = np.arange(200 * 512 + 100, 200 * 512 + 140)        # a stamp in one chunk
    src = VariableSource(idx, np.full(idx.size, 300.0), LightCurve.step(2.5 * 0.7, before=0.0, after=1.0))
    ro = Readout.from_reads([[k] for k in range(5)], nints=2)
    opts = {"exact": {}, "sparse": {}, "gauss": {"gauss_above": 20.0},
            "2d": {"arrivals": "2d"}}[case]

    def run(threads):
        eng = ChargeEngine(det, ro, rate=rate, variable_sources=[src], rng=5,
                           options=EngineOptions(threads=threads, **opts))
        layout = eng.poisson_layout
        assert len(layout["chunks"]) == 4 and layout["charged_pixels"] > 65536  # pool
        assert layout["reads_per_call"] == (2 if case == "sparse" else 1)
        charge, _ = _collect(eng)
        return charge, write_exposure(eng, None)["sci"]

    c1, s1 = run(1)
    c2, s2 = run(2)
    np.testing.assert_array_equal(c1, c2)
    np.testing.assert_array_equal(s1, s2)
    assert np.all(c1[:, :, det.reference_mask()] == 0)


@pytest.mark.parametrize("bits", [0, 17, 32, 12.5, True])
def test_adc_bits_must_fit_the_uint16_resultants(bits):
    """Resultants are uint16: more than 16 ADC bits would wrap, so they are refused."""
    det = Detector(name="T", naxis1=8, naxis2=8, n_out=1, nroh=0, nfoh=0, ref_border=0)
    with pytest.raises(ParameterError, match="adc_bits"):
        ChargeEngine(det, Readout.named("RAPID", 2), rate=1.0, adc_bits=bits, rng=1)


def test_engine_adc_is_the_definition_for_any_gain():
    # Each read is digitised as DN = clip(rint(float64(charge + noise) / gain)): one
    # ADC for every path (noise.adc).  Old behaviour: the engine divided in float32
    # by float32(gain), which for gains that are not powers of two (2.7 here) rounded
    # thousands of values the other way; new: the float64 quotient, as documented.
    import noise
    det = _det()
    params = noise.ZERO_NOISE.replace(rd_noise=7.0, bias_offset=2000.0)
    for gain in (2.0, 2.7):
        eng = ChargeEngine(det, Readout.from_reads([[0], [1], [2]]), noise_params=params,
                           rate=5e4, gain=gain, rng=5)
        with eng.simulate(save_charge=True, save_noise=True) as run:
            for res in run:
                total = (res.charge + res.noise).astype(np.float32)   # as the engine adds
                want = np.clip(np.rint(total.astype(np.float64) / gain), 0, 65535)
                np.testing.assert_array_equal(res.dn, want)


def test_fractional_full_well_holds_whole_electrons():
    # The well holds whole electrons: full_well = 1000.5 e- clips charge at 1000 e-,
    # as apply_saturation documents.  Old behaviour: the engine clipped at 1000.5
    # (its own copy of the step); new: the engine calls the one FullWell.
    det = _det()
    eng = ChargeEngine(det, Readout.from_reads([[0], [1]]), rate=1e6, full_well=1000.5,
                       rng=6)
    charge, out = _collect(eng)
    reg = ~det.reference_mask()
    np.testing.assert_array_equal(charge[0, :, reg], 1000.0)
    assert np.all(out["sat_read"][0][reg] == 0)


def test_stopping_a_run_early_releases_its_threads():
    # a run closed before its end (a consumer that stops, or an interrupt) shuts its
    # thread pool down and closes the noise generator: no thread is left behind
    import threading

    import noise
    det = preset("H2RG", naxis1=256, naxis2=256)
    eng = ChargeEngine(det, Readout.from_reads([[k] for k in range(6)]),
                       noise_params=noise.NIRSPEC_DEFAULTS, rate=1.0, rng=7,
                       options=EngineOptions(threads=2))
    before = threading.active_count()
    with eng.simulate() as run:
        first = next(run)
        assert first.index == 0
    assert threading.active_count() == before
    with pytest.raises(StopIteration):
        next(run)


def test_a_fractional_cosmic_ray_index_is_refused():
    # before: 330.7 was truncated to pixel 330 without a word
    from noise import ZERO_NOISE
    det = preset("H2RG", naxis1=32, naxis2=32)
    ro = Readout.named("RAPID", 2)
    with pytest.raises(ParameterError, match="'cosmic_rays index' must be integer"):
        ChargeEngine(det, ro, noise_params=ZERO_NOISE, rate=0.0, rng=1,
                     cosmic_rays=CosmicRayHits(np.array([0.1]), np.array([330.7]),
                                               np.array([100.0])))
    ChargeEngine(det, ro, noise_params=ZERO_NOISE, rate=0.0, rng=1,
                 cosmic_rays=CosmicRayHits(np.array([0.1]), np.array([330.0]),
                                           np.array([100.0])))
