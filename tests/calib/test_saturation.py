"""Saturation flags of :func:`scenesim.calib.saturation.saturation_flags` against closed
forms.

The ramps are simulated here, independently of the simulator: each pixel's charge
gets Poisson increments between consecutive reads at their exact times (rolling
reset: read k at ``(k + 1) t_frame``), is clipped at the full well ``FW``, made
nonlinear with ``m = q + c2 q^2 + c3 q^3``, coupled to its 4 nearest neighbours by
IPC (``scipy.signal.convolve2d`` with the kernel ``[[0, a, 0], [a, 1 - 4a, a],
[0, a, 0]]``), offset by a bias with a pixel pattern, and read with Gaussian read
noise; reads are averaged into resultants.  The read at which each pixel's own
charge first reaches ``FW`` is known exactly from the simulation.

What the defect was: a pixel held at ``FW`` reads ``(1 - 4a) p(FW) + a (sum of its
neighbours)``, 0.90-0.92 FW for the bright-star scene's coefficients, so a level test
at 97 % of ``FW`` never flags it, and the flat end of its ramp bends the slope.

The pipeline tests (engine exposures through ``prepare_exposure``) cover both cases:
IPC undone (the header records the kernel, ``IPCKERN``: flags on the pixels that
reach FW only, the ADC ceiling judged on the raw ramps and grown), and IPC kept
(``deconvolve_ipc=False`` or no ``IPCKERN``: flags grown to the 3 x 3 box).
"""

import numpy as np
import pytest
from scipy.signal import convolve2d

import noise
from noise.clock import preset
from noise.errors import ParameterError
from scenesim.detector.nonlinearity import Nonlinearity
from scenesim.detector.ipc import ipc_kernel
from scenesim.detector.dq import BAD_VARIANCE, DO_NOT_USE, SATURATED
from scenesim.rampfit import fit_ramps
from scenesim.detector.nonlinearity import linearize_resultants
from scenesim.calib.prepare import PrepareOptions, prepare_exposure
from scenesim.calib.saturation import SaturationOptions, saturation_flags
from scenesim.detector.readout import Readout
from scenesim.engine import ChargeEngine, EngineOptions
from scenesim.io.exposure import Exposure
from scenesim.run import write_exposure

FW = 8e4                      # e-, full well
C2, C3 = -8e-7, -2e-12        # nonlinearity: p(FW) = 0.923 FW
ALPHA = 0.015                 # IPC to each nearest neighbour
T_FRAME = 0.1806              # s
SIGMA = 10.0                  # e- per read
CEILING = 65535 * 2.0         # e-: 16-bit ADC at 2 e-/DN (never reached here)


def p(q):
    """The nonlinearity, written out (not the module's)."""
    return q + C2 * q ** 2 + C3 * q ** 3


def read_times(ngroups, nframes=1, groupgap=0):
    """MULTIACCUM read times from reset (rolling reset), one array per resultant."""
    return [(np.arange(nframes) + g * (nframes + groupgap) + 1) * T_FRAME
            for g in range(ngroups)]


def ramps(rng, rate, times, *, alpha=ALPHA, nonlinear=True, nints=1, poisson=True,
          sigma=SIGMA, bias_sigma=500.0):
    """Resultants (nints, nres, ny, nx) in e- and the first saturated resultant of
    each pixel's own charge, (nints, ny, nx) (-1: never)."""
    ny, nx = rate.shape
    nres = len(times)
    kern = np.array([[0, alpha, 0], [alpha, 1 - 4 * alpha, alpha], [0, alpha, 0]])
    res = np.zeros((nints, nres, ny, nx))
    first = np.full((nints, ny, nx), -1)
    for k in range(nints):
        bias = 5000.0 + bias_sigma * rng.standard_normal((ny, nx))
        q = np.zeros((ny, nx))
        prev = 0.0
        for r, tr in enumerate(times):
            for t in tr:
                mean = rate * (t - prev)
                q = q + (rng.poisson(mean) if poisson else mean)
                prev = t
                full = (q >= FW) & (first[k] < 0)
                first[k][full] = r
                m = np.minimum(q, FW)
                if nonlinear:
                    m = p(m)
                m = convolve2d(m, kern, mode="same")
                res[k, r] += m + bias + sigma * rng.standard_normal((ny, nx))
            res[k, r] /= len(tr)
    return res.astype(np.float32), first


def flags_for(e, times, *, nonlinear=True, grow=1, read_noise=SIGMA):
    tbar = np.array([t.mean() for t in times])
    t_last = np.array([t[-1] for t in times])
    nl = Nonlinearity((C2, C3)) if nonlinear else None
    opts = SaturationOptions(FW, CEILING, read_noise=read_noise, nonlinearity=nl,
                             grow=grow)
    return saturation_flags(e, tbar, opts, t_last=t_last,
                            n_reads=[len(t) for t in times])


def first_flag(sat):
    return np.where(sat.any(axis=1), sat.argmax(axis=1), -1)


def star(shape, centres, core):
    """Rate map: cores ``core`` e-/s, nearest neighbours 0.4 core, diagonals 0.15
    core, on 1 e-/s."""
    rate = np.ones(shape)
    for (y, x), f in zip(centres, core):
        rate[y - 1:y + 2, x - 1:x + 2] += f * np.array([[0.15, 0.4, 0.15],
                                                         [0.4, 1.0, 0.4],
                                                         [0.15, 0.4, 0.15]])
    return rate


# ---------------------------------------------------------------- closed form
def test_core_under_ipc_and_nonlinearity_flagged_at_its_full_well_read():
    # Noise-free: core 3.5e4 e-/s reaches FW at t = 2.286 s, between reads 11
    # (2.167 s, 0.948 FW) and 12 (2.348 s); its neighbours (1.4e4 e-/s) reach 0.63 FW
    # by the last read (3.612 s) and never saturate.
    times = read_times(20)
    rate = star((21, 21), [(10, 10)], [3.5e4])
    e, truth = ramps(np.random.default_rng(1), rate, times, poisson=False, sigma=0.0,
                     bias_sigma=0.0)
    assert truth[0, 10, 10] == 12 and np.sum(truth >= 0) == 1
    # The defect: at the last read the core reads (1 - 4a) p(FW) + a * 4 p(q_nn) =
    # 0.94 * 73856 + 0.06 * p(50568) = 72320 e- = 0.904 FW above its bias (5000 e-)
    # and never reaches the former threshold 0.97 FW above its zero level (the
    # first resultant extrapolated to the reset).
    plateau = (1 - 4 * ALPHA) * p(FW) + 4 * ALPHA * p((1 + 1.4e4) * times[-1][-1])
    assert e[0, -1, 10, 10] - 5000.0 == pytest.approx(plateau, abs=0.05)  # float32
    zero = 2 * e[0, 0, 10, 10] - e[0, 1, 10, 10]
    assert np.max(e[0, :, 10, 10] - zero) < 0.97 * FW
    own = flags_for(e, times, grow=0, read_noise=0.0)
    expected = np.full((1, 21, 21), -1)
    expected[0, 10, 10] = 12
    np.testing.assert_array_equal(first_flag(own), expected)
    # grown to the 3 x 3 box from the core's onset: the neighbours' ramps lose
    # a * 3.6e4 e-/s there
    grown = flags_for(e, times, grow=1, read_noise=0.0)
    expected[0, 9:12, 9:12] = 12
    np.testing.assert_array_equal(first_flag(grown), expected)
    assert np.all(np.diff(grown.astype(np.int8), axis=1) >= 0)       # sticky


@pytest.mark.parametrize("nframes, groupgap, ngroups, nints",
                         [(1, 0, 20, 1), (4, 1, 4, 2)], ids=["rapid", "nf4-2ints"])
def test_noisy_cores_flagged_within_one_resultant(nframes, groupgap, ngroups, nints):
    # 16 stars with cores 2.5e4-4e4 e-/s (FW reached after 2.0-3.2 s), Poisson and
    # read noise, a 500 e- bias pattern, 4-read resultants in the second case.  The
    # resultant holding the first saturated read must be flagged, +-1 resultant:
    # one early when the last unsaturated one is within 3 % of p(FW) (level test)
    # or its increment is 3 sigma short; one late when the saturation clipped the
    # resultant by less than 3 sigma of its increment.
    rng = np.random.default_rng(7)
    times = read_times(ngroups, nframes, groupgap)
    centres = [(8 + 12 * i, 8 + 12 * j) for i in range(4) for j in range(4)]
    rate = star((48, 48), centres, rng.uniform(2.5e4, 4e4, 16))
    e, truth = ramps(rng, rate, times, nints=nints)
    cy, cx = np.array(centres).T
    assert np.all(truth[:, cy, cx] >= 1)                   # every core saturates
    own = first_flag(flags_for(e, times, grow=0))
    assert np.all(np.abs(own[:, cy, cx] - truth[:, cy, cx]) <= 1)
    # no other pixel saturates (neighbours reach <= 0.72 FW) nor is flagged
    others = np.ones((48, 48), bool)
    others[cy, cx] = False
    assert np.all(truth[:, others] < 0) and np.all(own[:, others] < 0)


def test_bright_unsaturated_pixels_are_not_flagged():
    # Rates such that the charge at the last read spans 0.80-0.93 FW across the
    # columns of a 40 x 40 block (smooth, so IPC moves little), with IPC,
    # nonlinearity, Poisson and read noise, 2 integrations.  The level test's
    # margin: p(0.93 FW) = 0.936 p(FW), 2500 e- below 0.97 p(FW) against a noise of
    # ~100 e-; the flattening test needs an increment 5 sigma *and* half its
    # expected value short, P < 3e-7 per tested difference for Gaussian noise, so
    # over the 2 x 1600 x ~6 differences above the floor the expected number of
    # false flags is < 0.006: none is allowed.
    rng = np.random.default_rng(11)
    times = read_times(20)
    t_end = times[-1][-1]
    frac = np.linspace(0.80, 0.93, 40)
    rate = np.ones((48, 48))
    rate[4:44, 4:44] = frac[None, :] * FW / t_end
    e, truth = ramps(rng, rate, times, nints=2)
    assert np.all(truth < 0)
    assert not flags_for(e, times, grow=1).any()


def test_linear_data_saturate_at_the_full_well():
    # Without nonlinearity and IPC a full pixel reads FW: the same flags as the
    # closed form (core 3.5e4 e-/s: read 12, read 11 at 0.948 FW), no growth.
    times = read_times(20)
    rate = star((21, 21), [(10, 10)], [3.5e4])
    e, truth = ramps(np.random.default_rng(2), rate, times, alpha=0.0,
                     nonlinear=False, poisson=False, sigma=0.0, bias_sigma=0.0)
    flags = first_flag(flags_for(e, times, nonlinear=False, grow=0, read_noise=0.0))
    np.testing.assert_array_equal(flags, truth)


# ---------------------------------------------------------------- slopes
@pytest.mark.parametrize("nframes, groupgap, ngroups, nints",
                         [(1, 0, 20, 1), (4, 1, 6, 2)], ids=["rapid", "nf4-2ints"])
def test_partially_saturated_slopes_are_unbiased(nframes, groupgap, ngroups, nints):
    # 2500 pixels with nonlinearity (no IPC: isolated pixels have nothing to share)
    # whose charge reaches FW part-way through the ramp (after the third
    # resultant's last read, before 90 % of the ramp), Poisson and read noise.
    # Flag, linearise, fit with GLS; with the true rate as the variance rate,
    # z = (slope - rate) / sigma is N(0, 1) for an unbiased fit: |mean z| <
    # 5 / sqrt(n) = 0.1 (5 sigma of the mean).  With the former flags (97 % of FW
    # above the zero level, nonlinearity ignored) mean z was -230 for RAPID (the
    # plateau at p(FW) = 0.923 FW never flagged) and -1.3 for 4-read resultants
    # (flagged one resultant late in a quarter of the pixels).
    rng = np.random.default_rng(3)
    times = read_times(ngroups, nframes, groupgap)
    t_end = times[-1][-1]
    rate = FW / rng.uniform(1.05 * times[2][-1], 0.9 * t_end, (50, 50))
    e, truth = ramps(rng, rate, times, alpha=0.0, nints=nints)
    assert np.all(truth >= 3)
    tbar = np.array([t.mean() for t in times])
    sat = flags_for(e, times, grow=0)
    lin = linearize_resultants(e, Nonlinearity((C2, C3)), tbar)
    fit = fit_ramps(lin, times, read_noise=SIGMA, saturated=sat, variance_rate=rate)
    z = (fit.slope - rate) / np.sqrt(fit.var_read + fit.var_poisson)
    assert np.all(fit.dq == SATURATED)             # flagged, and measured
    assert abs(z.mean()) < 5 / np.sqrt(z.size)
    # and the variance is right: mean z^2 = 1 within 5 sqrt(2 / n) = 0.14
    assert abs(np.mean(z ** 2) - 1) < 5 * np.sqrt(2 / z.size)


# ---------------------------------------------------------------- full saturation
def test_fully_saturated_pixels_flagged_and_fitted_without_nan():
    # Pixel A is at FW before its first read (4e6 e-/s); pixel B holds 0.6 FW at
    # read 0 and FW at read 1.  A's first difference is flat, so its zero level
    # extrapolated from the ramp would be its plateau (the former rule never
    # flagged it); the zero level is bounded by the image's.  A: every resultant
    # flagged; B: from resultant 1 (its resultant 0, below the 0.75 p(FW) floor, is
    # usable).  Both are unmeasurable (at most one resultant): DO_NOT_USE |
    # SATURATED, slope 0, finite variances.  Their 3 x 3 neighbours are flagged
    # from the same resultants.
    rng = np.random.default_rng(5)
    times = read_times(10)
    rate = np.ones((24, 24))
    rate[6, 6] = 4e6
    rate[16, 16] = 0.6 * FW / T_FRAME
    e, truth = ramps(rng, rate, times, nints=2)
    assert np.all(truth[:, 6, 6] == 0) and np.all(truth[:, 16, 16] == 1)
    sat = flags_for(e, times, grow=1)
    first = first_flag(sat)
    expected = np.full((2, 24, 24), -1)
    expected[:, 5:8, 5:8] = 0
    expected[:, 15:18, 15:18] = 1
    np.testing.assert_array_equal(first, expected)
    fit = fit_ramps(e, times, read_noise=SIGMA, saturated=sat)
    for name in ("slope", "var_read", "var_poisson", "chi2", "slope_ints", "var_ints"):
        assert np.all(np.isfinite(getattr(fit, name))), name
    for y, x in ((6, 6), (16, 16)):
        assert fit.dq[y, x] == DO_NOT_USE | SATURATED
        assert fit.slope[y, x] == 0 and fit.var_read[y, x] == BAD_VARIANCE


def test_reference_pixels_with_a_high_bias_are_not_saturated():
    # Reference pixels collect no charge but may sit at another bias (1400-6200 e-
    # above the regular pixels in scenesim's noise model).  Here 8000 e- above: with
    # a full well FW' = 4000 e- they are ~5500 e- above the bound on the zero level
    # (median + 5 x 1.4826 MAD of the regular pixels' 500 e- bias pattern, ~2500
    # e-), beyond the level test's 0.97 FW' = 3880 e- even at -3 sigma of the
    # pattern (1500 e-): without ``refmask`` they are flagged from resultant 0.
    # With it only the ADC ceiling applies to them; the regular pixels are unchanged.
    rng = np.random.default_rng(9)
    times = read_times(6)
    e, _ = ramps(rng, np.full((16, 16), 10.0), times, alpha=0.0, nonlinear=False)
    ref = np.zeros((16, 16), bool)
    ref[:2] = True
    e[:, :, ref] += 8000.0
    tbar = np.array([t.mean() for t in times])
    fw = 4000.0
    opts = SaturationOptions(fw, CEILING)
    assert saturation_flags(e, tbar, opts)[:, :, ref].all()   # without refmask
    sat = saturation_flags(e, tbar, opts, refmask=ref)
    assert not sat.any()
    # the ADC ceiling still applies to them
    assert saturation_flags(e, tbar, SaturationOptions(fw, 5000.0),
                            refmask=ref)[:, :, ref].all()


# ---------------------------------------------------------------- pipeline
def _engine_exposure():
    """An engine exposure of the star above (RAPID: read = resultant; FW reached at
    read 12) with IPC and nonlinearity in the header, and the engine's record of the
    first read at FW per pixel."""
    det = preset("H2RG", naxis1=32, naxis2=32)
    ro = Readout.multiaccum(1, 20, name="RAPID")
    rate = star(det.shape, [(15, 16)], [3.5e4 * T_FRAME / det.frame_time])
    eng = ChargeEngine(det, ro, rate=rate, full_well=FW,
                       nonlinearity=Nonlinearity((C2, C3)),
                       ipc_kernel=ipc_kernel(ALPHA), gain=2.0,
                       noise_params=noise.NoiseParams(), rng=17,
                       options=EngineOptions(threads=1))
    out = write_exposure(eng, None)
    return out["exposure"], out["sat_read"].astype(np.int64)


def test_prepare_exposure_flags_engine_saturation_without_growth_once_ipc_undone():
    # The header records the IPC kernel, so prepare_exposure undoes it before the
    # flags: a full pixel then reads exactly p(FW) above its zero level and its
    # neighbours no longer bend when it stops collecting.  Every saturating pixel
    # is flagged within one resultant of the engine's first read at FW, and no
    # other pixel is flagged (formerly the 3 x 3 box was, from the core's onset).
    exp, truth = _engine_exposure()
    assert "IPCKERN" in exp.header and np.sum(truth >= 0) >= 1
    prep = prepare_exposure(exp,
                            options=PrepareOptions(remove_common_mode=False,
                                                   measure_noise=False))
    first = first_flag(prep.saturated)
    hit = truth >= 0
    assert np.all(np.abs(first[hit] - truth[hit]) <= 1)
    assert np.all(first[~hit] < 0)


def test_prepare_exposure_grows_flags_when_ipc_is_not_undone():
    # deconvolve_ipc=False, or a file from before IPCKERN existed (kernel unknown):
    # flags grown to the 3 x 3 box as JWST's n_pix_grow_sat = 1 -- every flag
    # within the box of a saturating pixel and not before its onset, every
    # saturating pixel within one resultant.
    exp, truth = _engine_exposure()
    old_header = exp.header.copy()
    del old_header["IPCKERN"]
    for prep in (prepare_exposure(exp,
                                  options=PrepareOptions(remove_common_mode=False,
                                                         measure_noise=False,
                                                         deconvolve_ipc=False)),
                 prepare_exposure(Exposure(exp.sci, old_header, exp.reads),
                                  options=PrepareOptions(remove_common_mode=False,
                                                         measure_noise=False))):
        first = first_flag(prep.saturated)
        hit = truth >= 0
        assert np.all(np.abs(first[hit] - truth[hit]) <= 1)
        # the earliest onset that can reach each pixel: its 3 x 3 box's
        onset = np.where(hit, truth, 10 ** 6)
        pad = np.pad(onset, ((0, 0), (1, 1), (1, 1)), constant_values=10 ** 6)
        box = np.min([pad[:, 1 + dy:33 + dy, 1 + dx:33 + dx]
                      for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)
        flagged = first >= 0
        assert np.all(box[flagged] < 10 ** 6)
        assert np.all(first[flagged] >= box[flagged] - 1)
        # grown: the whole box of the first saturating pixel is flagged
        y, x = np.argwhere(hit[0])[0]
        assert np.all(first[0, y - 1:y + 2, x - 1:x + 2] >= 0)


def test_adc_ceiling_is_judged_on_the_raw_ramps_and_grown_when_ipc_undone():
    # The ADC clip is not linear: undoing IPC would spread a clipped pixel's error
    # (alpha times the clipped signal) into its neighbours, so with IPC undone the
    # ceiling is tested on the raw ramps and its flags grown to the 3 x 3 box.
    # Here one dark pixel is set to the 16-bit ceiling from resultant 6 on.
    exp, truth = _engine_exposure()
    sci = exp.sci.copy()
    sci[0, 6:, 8, 9] = 65535
    prep = prepare_exposure(Exposure(sci, exp.header, exp.reads),
                            options=PrepareOptions(remove_common_mode=False,
                                                   measure_noise=False))
    first = first_flag(prep.saturated)
    np.testing.assert_array_equal(first[0, 7:10, 8:11], 6)
    assert np.all(first[0, 5:13, 5:14][first[0, 5:13, 5:14] != 6] < 0)


# ---------------------------------------------------------------- arguments
@pytest.mark.parametrize("kwargs, match", [
    (dict(floor=0.99), "floor"),
    (dict(floor=0.0), "floor"),
    (dict(grow=-1), "grow"),
    (dict(grow=1.5), "grow"),
    (dict(nsigma=0), "nsigma"),
    (dict(read_noise=-1.0), "read_noise"),
    (dict(n_reads=[1, 1]), "n_reads"),
    (dict(nonlinearity=(C2, C3)), "nonlinearity"),
    (dict(t_last=[1.0]), "t_last"),
    (dict(refmask=np.zeros((3, 3), bool)), "refmask"),
])
def test_saturation_flags_rejects_bad_arguments(kwargs, match):
    # Settings are checked when the options are made, the per-exposure arrays by
    # saturation_flags; both before any work.
    e = np.zeros((1, 3, 4, 4), np.float32)
    arrays = {k: kwargs.pop(k) for k in ("n_reads", "t_last", "refmask") if k in kwargs}
    with pytest.raises(ParameterError, match=match):
        saturation_flags(e, [1.0, 2.0, 3.0], SaturationOptions(FW, CEILING, **kwargs),
                         **arrays)


def test_saturation_flags_takes_its_settings_as_options():
    e = np.zeros((1, 3, 4, 4), np.float32)
    with pytest.raises(ParameterError, match="'options' must be a SaturationOptions"):
        saturation_flags(e, [1.0, 2.0, 3.0], FW)
    opts = SaturationOptions(FW, CEILING, fraction=1, floor=0.5, nsigma=3, grow=1)
    assert opts.fraction == 1.0 and isinstance(opts.fraction, float)
    assert opts.full_signal == FW       # no nonlinearity: p(FW) = FW
    nl = Nonlinearity((C2, C3))
    assert SaturationOptions(FW, CEILING, nonlinearity=nl).full_signal == \
        pytest.approx(p(FW))


def test_saturation_flags_use_the_last_read_of_a_resultant():
    # Resultants of 8 reads (MEDIUM8-like: 8 read, 2 skipped), zero level 0, rate
    # f: read at frame k holds min(f k t_f, FW).  Resultant 3 averages frames
    # 31..38, i.e. 83700..102600 e- with frame 38 clipped at the 1e5 e- full well:
    # its mean, 92825 e- (92.8 % FW), is below the 97 % threshold although the ramp
    # is bent.  Its last read, estimated from the initial slope (2700 e-/s) as
    # 92825 + 2700 (38 - 34.5) = 102275 e-, is above it.
    tf, fw, f = 1.0, 1e5, 2700.0
    reads = [np.arange(10 * g + 1, 10 * g + 9) * tf for g in range(5)]
    e = np.array([np.minimum(f * r, fw).mean() for r in reads], np.float32)
    e = e[None, :, None, None]
    tbar = np.array([r.mean() for r in reads])
    t_last = np.array([r[-1] for r in reads])
    # mean-based test (old behaviour): resultant 3 mean vs 0.97 FW
    assert e[0, 3, 0, 0] < 0.97 * fw
    old = saturation_flags(e, tbar, SaturationOptions(fw, 1e9))
    new = saturation_flags(e, tbar, SaturationOptions(fw, 1e9), t_last=t_last)
    # last read of resultant 3 (frame 38): f * 38 > FW -> saturated; resultant 2's
    # last read (frame 28): 75600 e- < 0.97 FW -> not.
    assert old[0, :, 0, 0].tolist() == [False, False, False, False, True]
    assert new[0, :, 0, 0].tolist() == [False, False, False, True, True]
