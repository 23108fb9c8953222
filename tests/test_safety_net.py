"""Safety net for the physics of the engine, through the public API only.

Each effect below is pinned by an engine-level (or scene-level) test against the
documented theory, not against another output of the code:

1. read times of rolling and global reset (``docs/CONVENTIONS.md``);
2. kTC reset noise (one level per pixel and integration);
3. white read noise (per read, not CDS; reference pixels scaled by ``ref_ratio``);
4. saturation at the full well, and the first saturated read;
5. the orientation of the 3x3 IPC kernel.

Only top-level names of :mod:`noise` and :mod:`scenesim` are used (no submodule, no
private attribute), so these tests survive moving modules around.  The measurements are
module-level functions taking the simulated parameter separately from the nominal one,
so that a throwaway script can run them with a perturbed simulation and check that the
assertions fail (see each test's comment for the numbers).
"""

import math

import numpy as np
import pytest

import noise
import scenesim

SEED = 20240611


# ----------------------------------------------------------------------- helpers
def small_detector(n=64):
    """Full-frame H2RG clocking (4 outputs, nroh 12, nfoh 1, 10 us) on n x n pixels."""
    return noise.preset("H2RG", naxis1=n, naxis2=n)


def engine(det, readout, *, rate=0.0, noise_params=None, shot_noise=False, rng=SEED,
           **kw):
    return scenesim.ChargeEngine(
        det, readout, noise_params=noise_params, rate=rate, rng=rng,
        options=scenesim.EngineOptions(shot_noise=shot_noise, threads=1), **kw)


def run(eng, *, save_charge=True, save_noise=False):
    """All resultants: ``(dn, charge, noise, sat_read)``, shape (nints, ngroups, ny, nx)."""
    ro = eng.readout
    shape = (ro.nints, ro.ngroups) + eng.detector.shape
    dn = np.zeros(shape, dtype=np.uint16)
    charge = np.full(shape, np.nan, dtype=np.float64) if save_charge else None
    nz = np.full(shape, np.nan, dtype=np.float64) if save_noise else None
    seen = np.zeros(shape[:2], dtype=bool)

    with eng.simulate(save_charge=save_charge, save_noise=save_noise) as run:
        for res in run:
            i, r = res.integration, res.index
            seen[i, r] = True
            dn[i, r] = res.dn
            if save_charge:
                charge[i, r] = 0.0 if res.charge is None else res.charge
            if save_noise:
                nz[i, r] = res.noise
    assert seen.all()
    return dn, charge, nz, run.sat_read


def documented_clock(det):
    """``t_pix`` (s) and ``t_frame`` (s) of a full-frame detector from the documented
    clock: ``t(y, x) = (y * (ncols_out + nroh) + x_fast) * dt`` with output ``o`` scanning
    left to right for even ``o`` and right to left for odd ``o``; a frame is
    ``(ny + nfoh) * (ncols_out + nroh) * dt``.  Independent of ``Detector.pixel_time``.
    """
    ncol = det.nx // det.n_out
    row = ncol + det.nroh
    t = np.empty(det.shape)
    for y in range(det.ny):
        for x in range(det.nx):
            out, local = divmod(x, ncol)
            fast = ncol - 1 - local if out % 2 == 1 else local
            t[y, x] = (y * row + fast) * det.dt
    return t, (det.ny + det.nfoh) * row * det.dt


def border_mask(shape, b=4):
    """Reference pixels of a full frame: the ``b``-pixel border."""
    m = np.zeros(shape, dtype=bool)
    m[:b], m[-b:], m[:, :b], m[:, -b:] = True, True, True, True
    return m


# ==================================================================== 1. reset timing
RESET_READS = [[0], [2, 3], [5]]       # a skipped read and a two-read resultant


def reset_timing_charge(reset_mode):
    """Noise-free charge resultants (nints=2) of a seeded random rate map, and the map."""
    det = small_detector()
    rate = np.random.default_rng(SEED).uniform(1e3, 1e4, det.shape)
    ro = scenesim.Readout.from_reads(RESET_READS, nints=2, reset_mode=reset_mode)
    dn, charge, _, _ = run(engine(det, ro, rate=rate))
    return det, rate, dn, charge


def expected_reset_charge(det, rate, reset_mode):
    """Resultants of ``rate`` from the read-time law, shape (ngroups, ny, nx)."""
    tpix, tf = documented_clock(det)
    rate = np.where(border_mask(det.shape), 0.0, rate)   # reference pixels collect none
    out = []
    for reads in RESET_READS:
        if reset_mode == "global":    # all pixels reset at the start of read frame 0
            t = [k * tf + tpix for k in reads]
        else:                         # each pixel reset one frame before its read 0
            t = [np.full(det.shape, (k + 1) * tf) for k in reads]
        out.append(rate * np.mean(t, axis=0))
    return np.array(out)


@pytest.mark.parametrize("reset_mode", ["global", "rolling"])
def test_reset_mode_read_times_per_pixel(reset_mode):
    det, rate, dn, charge = reset_timing_charge(reset_mode)
    tpix, tf = documented_clock(det)
    # the public clock is the documented one (the engine must use it below)
    np.testing.assert_allclose(det.pixel_time(), tpix, rtol=0, atol=1e-15)
    assert det.frame_time == pytest.approx(tf, rel=1e-15)
    expected = expected_reset_charge(det, rate, reset_mode)
    for i in range(2):                # the second integration is reset the same way
        # shot_noise=False: charge is rate * time in float64, stored as float32, so the
        # only error is float32 rounding (2**-24 ~ 6e-8 relative); rtol 1e-6.  The other
        # reset mode differs by at least (t_frame - max t_pix) / (6 t_frame) = 0.37 %
        # on this detector (last pixel, read 5), 3700x the tolerance.
        np.testing.assert_allclose(charge[i], expected, rtol=1e-6, atol=1e-9)
        # DN (gain 1, no noise): the rounded mean of rounded reads is within 1 DN
        assert np.max(np.abs(dn[i] - expected)) <= 1.0


def global_first_read_row_means(reset_mode, rate=2000.0, nints=8):
    """Shot-noise first-read charge (global-reset theory), mean per regular row.

    Returns ``(measured, expected, sigma)`` per regular row: the measured mean over the
    regular pixels of the row and the ``nints`` integrations, the global-reset mean
    ``rate * mean(t_pix)`` and its Poisson standard error ``sqrt(sum lambda) / n``.
    """
    det = small_detector()
    ro = scenesim.Readout.from_reads([[0]], nints=nints, reset_mode=reset_mode)
    _, charge, _, _ = run(engine(det, ro, rate=rate, shot_noise=True))
    tpix, _ = documented_clock(det)
    rows, cols = slice(4, det.ny - 4), slice(4, det.nx - 4)
    lam = rate * tpix[rows, cols]                       # global reset, read 0
    n = lam.shape[1] * nints
    measured = charge[:, 0, rows, cols].mean(axis=(0, 2))
    expected = lam.mean(axis=1)
    sigma = np.sqrt(lam.sum(axis=1) * nints) / n
    return measured, expected, sigma


def test_global_reset_poisson_first_read_by_row():
    measured, expected, sigma = global_first_read_row_means("global")
    # Each row mean averages n = 56 pixels x 8 integrations of independent Poisson
    # counts of mean lambda = rate * t_pix (2.2 to 33 e-), so its standard error is
    # sqrt(sum lambda) / n.  5 sigma per row: false-alarm chance 56 x 5.7e-7 = 3e-5.
    # Measured: max |z| = 3.2 over the 56 rows; the same run with rolling reset
    # (lambda = rate * t_frame on every row) gives max |z| = 466.
    z = (measured - expected) / sigma
    assert np.max(np.abs(z)) < 5.0, z
    # the law is visible: the expected means rise 14-fold from the first to the last row
    assert expected[-1] / expected[0] > 10


# ============================================================================ 2. kTC
KTC = 29.0


def ktc_levels(ktc, n=128, nints=8):
    """Noise-only resultants (RAPID x 2, ``nints``) with only kTC on, via the engine."""
    det = small_detector(n)
    ro = scenesim.Readout.named("RAPID", 2, nints=nints)
    # the bias (a constant) 10 kTC sigmas above the ADC's code 0: nothing clips
    params = noise.ZERO_NOISE.replace(ktc=ktc, bias_offset=10 * ktc)
    _, _, nz, _ = run(engine(det, ro, noise_params=params), save_charge=False,
                      save_noise=True)
    return det, nz - 10 * ktc


def ktc_statistics(ktc):
    det, nz = ktc_levels(ktc)
    lvl = nz[:, 0]                                   # (nints, ny, nx)
    ref = border_mask(det.shape)
    return {
        "same_across_reads": bool(np.array_equal(nz[:, 0], nz[:, 1])),
        "rms": math.sqrt(np.mean(lvl ** 2)),
        "n": lvl.size,
        "mean": float(lvl.mean()),
        "rms_ref": math.sqrt(np.mean(lvl[:, ref] ** 2)),
        "n_ref": lvl[:, ref].size,
        # lag-1 correlation between the levels of consecutive integrations (pooled)
        "corr": float(np.mean(lvl[1:] * lvl[:-1]) / np.mean(lvl ** 2)),
        "n_corr": lvl[1:].size,
    }


def test_ktc_sigma_through_engine():
    s = ktc_statistics(KTC)
    # one reset level per pixel and integration: every read of it sees the same value
    assert s["same_across_reads"]
    # kTC is a zero-mean N(0, ktc^2) level (bias_offset 0).  With the mean known (0) the
    # estimator sqrt(mean(x^2)) of sigma has relative standard error 1/sqrt(2N)
    # (Var(x^2) = 2 sigma^4, then the delta method halves the relative error); the
    # sample std would have 1/sqrt(2(N-1)), the same here.  N = 8 integrations x
    # 128 x 128 pixels = 131072: 1/sqrt(2N) = 0.195 %, 5 sigma = 0.98 %, so a 3 % error
    # in the amplitude fails by > 10 standard errors (measured: the nominal run is off
    # by -0.16 %; simulating ktc x 1.03 gives +2.84 %, ktc x 0.97 gives -3.15 %).
    tol = 5.0 / math.sqrt(2.0 * s["n"])
    assert abs(s["rms"] / KTC - 1.0) < tol, (s["rms"], KTC, tol)
    # mean 0: standard error sigma/sqrt(N) = 0.08 e-, 5 sigma = 0.40 e-
    assert abs(s["mean"]) < 5.0 * KTC / math.sqrt(s["n"])
    # reference pixels are reset like regular ones (no ref_ratio on kTC): 8 x 1984
    # values, 5 sigma = 5/sqrt(2 x 15872) = 2.8 %
    tol_ref = 5.0 / math.sqrt(2.0 * s["n_ref"])
    assert abs(s["rms_ref"] / KTC - 1.0) < tol_ref, (s["rms_ref"], tol_ref)
    # redrawn each integration: the correlation of consecutive integrations' levels is
    # 0 with standard error 1/sqrt(N_pairs) (7 x 16384 pairs: 0.0030; 5 sigma 0.015);
    # a level reused across integrations would give 1
    assert abs(s["corr"]) < 5.0 / math.sqrt(s["n_corr"]), s["corr"]


# ====================================================================== 3. white noise
RD_NOISE = 5.2
REF_RATIO = 0.8


def white_pair_differences(rd_noise, ref_ratio, n=256, nreads=20):
    """Non-overlapping frame differences (read 2j+1 - read 2j) of the noise-only
    resultants (RAPID, white noise only), via the engine: ``(regular, reference)``
    flattened values."""
    det = small_detector(n)
    ro = scenesim.Readout.named("RAPID", nreads)
    # the bias 10 sigmas above the ADC's code 0 (differences cancel it)
    params = noise.ZERO_NOISE.replace(rd_noise=rd_noise, ref_ratio=ref_ratio,
                                      bias_offset=10 * rd_noise * max(1.0, ref_ratio))
    _, _, nz, _ = run(engine(det, ro, noise_params=params), save_charge=False,
                      save_noise=True)
    d = nz[0, 1::2] - nz[0, 0::2]                    # (nreads/2, ny, nx), independent
    ref = border_mask(det.shape)
    return d[:, ~ref].ravel(), d[:, ref].ravel()


def test_white_read_noise_per_read_through_engine():
    reg, ref = white_pair_differences(RD_NOISE, REF_RATIO)
    # Read noise is per read: a difference of two independent reads has sigma
    # sqrt(2) rd_noise (sqrt(2) rd_noise ref_ratio on reference pixels).  The pairs
    # (1,0), (3,2), ... share no read, so all values are independent N(0, s^2); with
    # the mean known, sqrt(mean(d^2)) has relative standard error 1/sqrt(2N).
    # Regular: N = 10 pairs x 248^2 = 615040, 1/sqrt(2N) = 0.090 %, 5 sigma = 0.45 %,
    # so a 1 % error in rd_noise fails by 6 standard errors (measured: nominal -0.05 %;
    # simulating rd_noise x 1.01 gives +0.95 %, x 0.99 gives -1.05 %).
    expected = math.sqrt(2.0) * RD_NOISE
    tol = 5.0 / math.sqrt(2.0 * reg.size)
    assert tol < 0.005
    measured = math.sqrt(np.mean(reg ** 2))
    assert abs(measured / expected - 1.0) < tol, (measured, expected, tol)
    # Reference: N = 10 x (256^2 - 248^2) = 39680, 5 sigma = 1.8 % (measured: nominal
    # +0.27 %; ref_ratio x 1.03 gives +3.28 %)
    expected_ref = math.sqrt(2.0) * RD_NOISE * REF_RATIO
    tol_ref = 5.0 / math.sqrt(2.0 * ref.size)
    measured_ref = math.sqrt(np.mean(ref ** 2))
    assert abs(measured_ref / expected_ref - 1.0) < tol_ref, (measured_ref, expected_ref)


# ======================================================================= 4. full well
WELL = 5000.0
# MULTIACCUM nframes 2, groupgap 1: reads (0,1) (3,4) (6,7) (9,10) (12,13); 2, 5, 8, 11
# are skipped
FW_READOUT = dict(nframes=2, ngroups=5, groupgap=1)


def full_well_case(kind):
    """Rate map, full-well map and the special pixels of the full-well test."""
    det = small_detector()
    tf = det.frame_time
    g = np.random.default_rng(SEED + 1)
    if kind == "map":                # asymmetric map: a transposed map would fail
        well = WELL * (0.8 + 0.4 * g.random(det.shape))
    else:
        well = np.full(det.shape, WELL)
    # log-uniform rates: wells filled at any read from 0 (rate t_frame > W) to never
    # (14 rate t_frame < W)
    rate = well / tf * np.exp(g.uniform(np.log(1 / 30), np.log(1.2), det.shape))
    special = {
        # crosses W by only 0.5 % at needed read 6 (read 4: 0.72 W): sat_read 6
        "D": ((20, 33), 1.005 / 7.0, 6),
        # crosses W at the skipped read 2 (read 1: 0.67 W): reported at the next
        # needed read, 3
        "E": ((41, 12), 1.001 / 3.0, 3),
        # never reaches W (read 13: 0.93 W): untouched
        "F": ((9, 50), 0.93 / 14.0, -1),
    }
    for (y, x), frac, _ in special.values():
        rate[y, x] = frac * well[y, x] / tf
    return det, rate, well, special


def full_well_run(kind, sim_scale=1.0):
    """Run the engine with the full well scaled by ``sim_scale`` (1: nominal)."""
    det, rate, well, special = full_well_case(kind)
    ro = scenesim.Readout.multiaccum(**FW_READOUT)
    sim_well = WELL * sim_scale if kind == "scalar" else well * sim_scale
    eng = engine(det, ro, rate=rate, full_well=sim_well)
    dn, charge, _, sat = run(eng)
    return det, rate, well, special, ro, dn, charge, sat


def expected_full_well(det, rate, well, ro):
    """Resultants and first saturated needed read from rolling-reset theory."""
    tf = det.frame_time
    ref = border_mask(det.shape)
    rate = np.where(ref, 0.0, rate)
    res = np.array([np.mean([np.minimum(rate * (k + 1) * tf, well) for k in reads],
                            axis=0) for reads in ro.resultants])
    sat = np.full(det.shape, -1)
    for k in reversed([k for reads in ro.resultants for k in reads]):
        sat = np.where(rate * (k + 1) * tf >= well, k, sat)
    return res, sat


@pytest.mark.parametrize("kind", ["scalar", "map"])
def test_full_well_through_engine(kind):
    det, rate, well, special, ro, dn, charge, sat = full_well_run(kind)
    exp_res, exp_sat = expected_full_well(det, rate, well, ro)
    # charge: float64 arithmetic stored in float32, rtol 1e-6 (float32 eps 6e-8).  A
    # 1 % larger well leaves every saturated pixel 1 % (50 e-) too high: 10^4 x the
    # tolerance (measured: simulating 1.01 W gives max relative error 1.0e-2, DN off
    # by 50, 75 wrong first-saturated reads, pixel D reported at read 7).
    np.testing.assert_allclose(charge[0], exp_res, rtol=1e-6, atol=1e-9)
    # DN at gain 1: saturated reads are exactly W; a resultant of two rounded reads is
    # within 1 DN of the mean charge
    assert np.max(np.abs(dn[0] - exp_res)) <= 1.0
    # pixels full at both reads (12, 13) of the last resultant read exactly W
    full = (rate * 13 * det.frame_time >= well) & ~border_mask(det.shape)
    assert full.sum() > 100
    assert np.all(dn[0, -1][full] == np.rint(well[full]))
    assert np.all(charge[0, -1][full] == well[full].astype(np.float32))
    # pixels that never reach W are untouched: rate x time exactly (float32)
    never = exp_sat == -1
    assert never.sum() > 100
    # first saturated read, per pixel, against rate * (k + 1) t_frame >= W
    np.testing.assert_array_equal(sat[0], exp_sat)
    for name, ((y, x), _, k_sat) in special.items():
        assert sat[0, y, x] == k_sat, (name, int(sat[0, y, x]), k_sat)
    # each saturation read 0..13 that can be reported occurs (the test covers them all)
    assert set(np.unique(exp_sat)) >= {-1, 0, 1, 3, 4, 6, 7, 9, 10, 12, 13}


SCENE_BG_FRACTION = 1.004 / 5.0       # of W per frame: crosses W by 0.4 % at read 4


def scene_full_well_run(tmp_path, sim_well):
    """Scene with a uniform background saturating at read 4 (nominal W), full well
    ``sim_well`` in the scene, run to files; returns ``(det, sci, truth, bg)``."""
    det = small_detector()
    bg = SCENE_BG_FRACTION * WELL / det.frame_time
    scene = scenesim.parse_scene({
        "seed": SEED,
        "detector": {"preset": "H2RG", "naxis1": 64, "naxis2": 64},
        "noise": {"preset": "none"},
        "readout": {"pattern": "RAPID", "ngroups": 8},
        "sources": {"background": bg},
        "effects": {"full_well": sim_well, "gain": 1.0},
        "output": {"path": str(tmp_path / "fw.fits"), "truth": True,
                   "save_charge": True},
    })
    result = scenesim.run_scene(
        scene, options=scenesim.EngineOptions(shot_noise=False, threads=1),
        progress=False)
    sci = scenesim.read_exposure(result.exposure)[0]
    truth = scenesim.read_truth(result.truth)
    return det, np.asarray(sci, dtype=np.float64), truth, bg


def test_full_well_scene(tmp_path):
    det, sci, truth, bg = scene_full_well_run(tmp_path, WELL)
    ref = border_mask(det.shape)
    k = np.arange(8)
    q = np.minimum(bg * (k + 1) * det.frame_time, WELL)     # 0.2 W, 0.4 W, ... , W
    expected = np.where(ref, 0.0, q[:, None, None])
    # one-read resultants at gain 1, no noise: DN = rint(charge), within 0.5 DN.  A 1 %
    # larger well leaves read 4 at 1.004 W = W + 20 DN and reads 5-7 at 1.01 W = W + 50
    assert np.max(np.abs(sci[0] - expected)) <= 0.5
    np.testing.assert_allclose(truth["CHARGE"][0], expected, rtol=1e-6, atol=1e-9)
    sat = truth["SATREAD"][0]
    assert np.all(sat[~ref] == 4) and np.all(sat[ref] == -1)


# ============================================================================ 5. IPC
# all nine entries distinct, so any transpose, flip or rotation changes some entry
K_RAW = np.array([[1.0, 20.0, 2.0], [10.0, 900.0, 30.0], [3.0, 40.0, 4.0]])
KERNEL = K_RAW / K_RAW.sum()          # sum 1010


def ipc_engine_run(sim_kernel, y0=20, x0=37, nreads=5):
    """One charged pixel at (y0, x0), noise off, no shot noise, IPC ``sim_kernel``."""
    det = small_detector()
    rate = np.zeros(det.shape)
    q_last = 60000.0                   # e- at the last read (16-bit DN at gain 1)
    rate[y0, x0] = q_last / (nreads * det.frame_time)
    ro = scenesim.Readout.named("RAPID", nreads)
    dn, charge, _, _ = run(engine(det, ro, rate=rate, ipc_kernel=sim_kernel))
    q = rate[y0, x0] * (np.arange(nreads) + 1) * det.frame_time
    return det, dn[0], charge[0], q, (y0, x0)


def ipc_expected(shape, q, y0, x0):
    """``out[y0 + dy, x0 + dx] = KERNEL[1 + dy, 1 + dx] * q`` (the documented
    convention), zero elsewhere; shape (len(q), ny, nx)."""
    out = np.zeros((len(q),) + shape)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            out[:, y0 + dy, x0 + dx] = KERNEL[1 + dy, 1 + dx] * q
    return out


def test_ipc_orientation_through_engine():
    det, dn, charge, q, (y0, x0) = ipc_engine_run(KERNEL)
    expected = ipc_expected(det.shape, q, y0, x0)
    # e.g. the pixel below (y0 - 1, x0) gets 20/1010 and the one right of it (x0 + 1)
    # 30/1010 of the charge.  Charge: float32 rounding only (rtol 1e-6 of the total);
    # the smallest neighbour gets 59 e- at the last read, and a transposed kernel moves
    # 10/1010 x 60000 = 594 e- between (y0-1, x0) and (y0, x0-1).
    np.testing.assert_allclose(charge, expected, rtol=0, atol=1e-6 * q.max())
    # DN at gain 1: rint of the float32 charge, within 0.5 DN plus the charge tolerance
    assert np.max(np.abs(dn - expected)) <= 0.5 + 1e-6 * q.max()
    # charge is conserved (the pixel is far from the edges)
    np.testing.assert_allclose(charge.sum(axis=(1, 2)), q, rtol=1e-6)


def test_apply_ipc_hand_computed():
    # single pixel of 1010 e- at (y, x) = (2, 3) of a 5 x 6 image: the neighbour at
    # (2 + dy, 3 + dx) receives K_RAW[1 + dy, 1 + dx]
    img = np.zeros((5, 6))
    img[2, 3] = 1010.0
    expected = np.array([
        [0, 0, 0, 0, 0, 0],
        [0, 0, 1, 20, 2, 0],
        [0, 0, 10, 900, 30, 0],
        [0, 0, 3, 40, 4, 0],
        [0, 0, 0, 0, 0, 0],
    ], dtype=float)
    np.testing.assert_allclose(scenesim.apply_ipc(img, KERNEL), expected, rtol=0,
                               atol=1e-9)
    # corner pixel (0, 0): the charge bound for row -1 or column -1 (kernel row 0:
    # 1 + 20 + 2, kernel column 0: 10 + 3) stays in the pixel: 900 + 36 = 936
    img = np.zeros((3, 4))
    img[0, 0] = 1010.0
    expected = np.array([
        [936, 30, 0, 0],
        [40, 4, 0, 0],
        [0, 0, 0, 0],
    ], dtype=float)
    np.testing.assert_allclose(scenesim.apply_ipc(img, KERNEL), expected, rtol=0,
                               atol=1e-9)
    # a random image against a direct loop over the documented sum (edges: kept)
    rng = np.random.default_rng(SEED)
    img = rng.uniform(0, 100, (6, 7))
    ref = np.zeros_like(img)
    ny, nx = img.shape
    for y in range(ny):
        for x in range(nx):
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    yy, xx = y + dy, x + dx
                    if 0 <= yy < ny and 0 <= xx < nx:
                        ref[yy, xx] += KERNEL[1 + dy, 1 + dx] * img[y, x]
                    else:
                        ref[y, x] += KERNEL[1 + dy, 1 + dx] * img[y, x]
    np.testing.assert_allclose(scenesim.apply_ipc(img, KERNEL), ref, rtol=1e-12,
                               atol=1e-12)
