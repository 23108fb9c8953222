"""Tests of scenesim.sky.lightcurve: exact integrals against closed forms and quadrature."""

import math
import pickle

import numpy as np
import pytest
from astropy import units as u
from astropy.table import Table
from scipy.integrate import quad

from noise.errors import FileFormatError, ParameterError
from scenesim.sky.lightcurve import LightCurve


def test_integral_matches_quad_for_random_curve():
    rng = np.random.default_rng(201)
    t = np.cumsum(rng.uniform(0.5, 3.0, 12))
    f = rng.uniform(0.0, 2.0, 12)
    lc = LightCurve(t, f)

    def s(x):      # independent piecewise-linear evaluation, constant beyond the ends
        return np.interp(x, t, f)

    t1 = rng.uniform(t[0] - 5, t[-1] + 5, 30)
    t2 = t1 + rng.uniform(0, 15, 30)
    got = lc.integral(t1, t2)
    for a, b, g in zip(t1, t2, got):
        ref, err = quad(s, a, b, points=t[(t > a) & (t < b)], limit=100, epsabs=1e-12)
        # quad is exact on each linear piece up to its own error estimate
        assert g == pytest.approx(ref, abs=1e-10 + 10 * err)


def test_transit_area_and_shape():
    t0, dur, depth, ing = 500.0, 120.0, 0.02, 15.0
    lc = LightCurve.transit(t0, dur, depth, ing)
    # trapezoid: area removed = depth * (duration - ingress)
    removed = 1000.0 - lc.integral(0.0, 1000.0)
    assert removed == pytest.approx(depth * (dur - ing), rel=1e-12)
    assert lc(t0) == pytest.approx(1 - depth)
    assert lc(t0 - dur / 2 + ing / 2) == pytest.approx(1 - depth / 2)
    assert lc(0.0) == 1.0 and lc(1e6) == 1.0
    # box (ingress 0) uses exact steps; triangle (ingress = duration/2)
    box = LightCurve.transit(t0, dur, depth, 0.0)
    assert 1000.0 - box.integral(0.0, 1000.0) == pytest.approx(depth * dur, rel=1e-12)
    tri = LightCurve.transit(t0, dur, depth, dur / 2)
    assert 1000.0 - tri.integral(0.0, 1000.0) == pytest.approx(depth * dur / 2, rel=1e-12)


def test_step_is_exact():
    lc = LightCurve.step(10.0, before=0.5, after=2.0)
    t1 = np.array([0.0, 5.0, 10.0, 12.0, 9.999])
    t2 = np.array([20.0, 10.0, 11.0, 15.0, 10.001])
    expected = (0.5 * (np.minimum(t2, 10) - np.minimum(t1, 10))
                + 2.0 * (np.maximum(t2, 10) - np.maximum(t1, 10)))
    assert np.allclose(lc.integral(t1, t2), expected, rtol=1e-14, atol=1e-15)
    # right-continuous: the new value from t_on on
    assert lc(9.999999) == 0.5 and lc(10.0) == 2.0
    assert lc.mean(10.0, 10.0) == 2.0


def test_step_default_before_is_one():
    # Old behaviour: LightCurve.step defaulted to before=0 (a star off until t_on)
    # while the scene's step light curve defaulted to before=1.  New: one default,
    # before=1, on every path; 'after' has no default (a step to 1 would be constant).
    lc = LightCurve.step(10.0, after=3.0)
    assert lc(9.999) == 1.0 and lc(-1e6) == 1.0 and lc(10.0) == 3.0
    assert lc.integral(0.0, 20.0) == pytest.approx(10.0 * 1.0 + 10.0 * 3.0, rel=1e-15)
    with pytest.raises(TypeError, match="after"):
        LightCurve.step(10.0)


def test_integral_broadcasts_is_signed_and_additive():
    lc = LightCurve([0.0, 10.0, 20.0, 20.0, 30.0], [1.0, 3.0, 2.0, 0.0, 4.0])
    t1 = np.linspace(-5, 35, 7)[:, None]
    t2 = np.linspace(-3, 40, 5)[None, :]
    res = lc.integral(t1, t2)
    assert res.shape == (7, 5)
    assert np.allclose(lc.integral(t2, t1), -res, rtol=0, atol=1e-12)
    mid = 0.5 * (t1 + t2)
    assert np.allclose(lc.integral(t1, mid) + lc.integral(mid, t2), res, rtol=0,
                       atol=1e-12)
    # constant beyond the ends
    assert lc.integral(-100.0, -90.0) == pytest.approx(10.0)
    assert lc.integral(100.0, 110.0) == pytest.approx(40.0)
    assert lc.mean([0.0, 20.0], [10.0, 30.0]) == pytest.approx([2.0, 2.0])


def test_short_interval_at_late_time_keeps_precision():
    lc = LightCurve([0.0, 1e6], [1.0, 3.0])
    t1 = 7.5e5 + 0.123
    t2 = t1 + 1e-5
    width = t2 - t1                 # exact in float64 (Sterbenz), ~1e-5 s
    exact = width * (1.0 + (t1 + t2) / 1e6)
    # Within one segment the integral is width * mean value: a few eps relative.
    # A difference of antiderivatives would lose eps * 1.5e6 / 2.5e-5 ~ 1e-5.
    assert lc.integral(t1, t2) == pytest.approx(exact, rel=1e-13)


def test_flare_integral_within_documented_bound():
    t0, amp, rise, decay, tol = 300.0, 2.5, 20.0, 40.0, 1e-4
    lc = LightCurve.flare(t0, amp, rise, decay, tol=tol)
    excess = lc.integral(0.0, 5000.0) - 5000.0
    exact = amp * (rise / 2 + decay)
    bound = tol * amp * decay * (1 + math.log(1 / tol))
    assert abs(excess - exact) <= bound
    # pointwise: the interpolated decay lies above the exponential by <= tol * amp
    tt = np.linspace(t0, t0 + decay * math.log(1 / tol), 2001)
    diff = lc(tt) - (1 + amp * np.exp(-(tt - t0) / decay))
    assert diff.min() >= -1e-12 and diff.max() <= tol * amp
    # the rise is exactly linear; a zero rise is an exact step
    assert lc(t0 - rise / 2) == pytest.approx(1 + amp / 2, rel=1e-14)
    step = LightCurve.flare(t0, amp, 0.0, decay)
    assert step(t0 - 1e-9) == 1.0 and step(t0) == pytest.approx(1 + amp)


def flare_exact(t, t0, amp, rise, decay):
    """The flare of the docstring: 1, a linear rise over ``rise`` s to 1 + amp at t0,
    then an exponential decay."""
    t = np.asarray(t, dtype=float)
    up = 1 + amp * np.clip((t - (t0 - rise)) / rise, 0, 1) if rise > 0 else \
        np.where(t < t0, 1.0, 1 + amp)
    return np.where(t < t0, up, 1 + amp * np.exp(-(t - t0) / decay))


def flare_exact_integral(a, b, t0, amp, rise, decay):
    """Closed-form integral of :func:`flare_exact` over [a, b] (a <= b)."""
    def F(t):          # antiderivative, F(t0 - rise) = t0 - rise
        t = np.asarray(t, dtype=float)
        t_start = t0 - rise
        u = np.clip(t - t_start, 0, rise)               # time into the rise
        rise_part = amp * u ** 2 / (2 * rise) if rise > 0 else 0.0 * u
        v = np.maximum(t - t0, 0)                       # time into the decay
        decay_part = amp * decay * -np.expm1(-v / decay)
        return t + rise_part + decay_part
    return F(b) - F(a)


def test_flare_shape_and_interval_integrals_match_the_closed_form():
    # The docstring's flare: s = 1 before t0 - rise, linear up to 1 + A at t0, then
    # 1 + A exp(-(t - t0)/decay).  The rise is exact; the decay is a piecewise-linear
    # interpolation within tol * A of the exponential (method notes), so over any
    # interval |integral - exact| <= tol * A * (length after t0).
    t0, amp, rise, decay, tol = 300.0, 2.5, 20.0, 40.0, 1e-4
    lc = LightCurve.flare(t0, amp, rise, decay, tol=tol)
    # values at chosen times: quiescent, on the rise, at the peak, in the decay
    t_rise = np.array([t0 - rise - 5, t0 - rise, t0 - 15, t0 - 10, t0 - 1e-6])
    np.testing.assert_allclose(lc(t_rise), flare_exact(t_rise, t0, amp, rise, decay),
                               rtol=1e-13)
    assert lc(t0 - rise / 4) == pytest.approx(1 + 0.75 * amp, rel=1e-14)
    assert lc(t0) == pytest.approx(1 + amp, rel=1e-14)
    t_decay = t0 + np.array([0.0, 1.0, decay, 3 * decay, 10 * decay, 30 * decay])
    assert np.all(np.abs(lc(t_decay) - flare_exact(t_decay, t0, amp, rise, decay))
                  <= tol * amp)
    assert lc(t0 + decay) == pytest.approx(1 + amp / np.e, abs=tol * amp)
    # interval integrals, as the engine takes them
    rng = np.random.default_rng(202)
    a = rng.uniform(t0 - 2 * rise, t0 + 12 * decay, 200)
    b = a + rng.uniform(0, 3 * decay, 200)
    got = lc.integral(a, b)
    exact = flare_exact_integral(a, b, t0, amp, rise, decay)
    after_peak = np.maximum(b, t0) - np.maximum(a, t0)
    assert np.all(np.abs(got - exact) <= tol * amp * after_peak + 1e-12 * b)
    # within the rise (and before it) the integral is exact
    a = np.linspace(t0 - 2 * rise, t0 - 1, 50)
    b = np.minimum(a + rng.uniform(0, rise, 50), t0)
    np.testing.assert_allclose(lc.integral(a, b),
                               flare_exact_integral(a, b, t0, amp, rise, decay),
                               rtol=1e-12, atol=1e-12)


def test_from_file_ecsv_and_fits(tmp_path):
    tab = Table({"TIME": [0.0, 1.0, 2.0] * u.min, "Flux": [1.0, 0.5, 1.0]})
    for name in ("lc.ecsv", "lc.fits"):
        path = tmp_path / name
        tab.write(path)
        lc = LightCurve.from_file(path)
        assert np.allclose(lc.time, [0.0, 60.0, 120.0])
        assert lc.integral(0.0, 120.0) == pytest.approx(90.0)
    Table({"time": [0.0, 1.0]}).write(tmp_path / "bad.ecsv")
    with pytest.raises(FileFormatError, match=r"flux"):
        LightCurve.from_file(tmp_path / "bad.ecsv")
    with pytest.raises(FileFormatError, match="does not exist"):
        LightCurve.from_file(tmp_path / "missing.ecsv")



def test_from_file_refuses_a_flux_that_is_no_factor(tmp_path):
    # A tester's probe: a 0..0.01 mag dip read as factors 0..0.01, and the star
    # vanished silently.  A flux unit that is not dimensionless is refused, naming
    # the file, the column and the unit; '%' is converted; no unit is a factor.
    for unit in (u.mag, u.Jy, u.electron / u.s):
        path = tmp_path / f"lc_{unit.to_string().replace(' / ', '_')}.ecsv"
        Table({"time": [0.0, 1.0, 2.0], "Flux": [0.0, 0.01, 0.0] * unit}).write(path)
        with pytest.raises(FileFormatError) as info:
            LightCurve.from_file(path)
        msg = str(info.value)
        assert str(path) in msg and "'Flux'" in msg and repr(unit.to_string()) in msg
        assert "\n" not in msg
    path = tmp_path / "pc.fits"
    Table({"time": [0.0, 1.0], "flux": [100.0, 99.0] * u.percent}).write(path)
    np.testing.assert_allclose(LightCurve.from_file(path).flux, [1.0, 0.99])
    path = tmp_path / "none.ecsv"
    Table({"time": [0.0, 1.0],
           "flux": [1.0, 0.5] * u.dimensionless_unscaled}).write(path)
    np.testing.assert_allclose(LightCurve.from_file(path).flux, [1.0, 0.5])

def test_value_semantics():
    a = LightCurve([0.0, 1.0], [1.0, 2.0])
    b = LightCurve(np.array([0.0, 1.0]), np.array([1.0, 2.0]))
    assert a == b and hash(a) == hash(b)
    assert a != LightCurve([0.0, 1.0], [1.0, 2.5])
    c = pickle.loads(pickle.dumps(a))
    assert c == a and c.integral(0, 1) == a.integral(0, 1)
    assert not a.time.flags.writeable and not a.flux.flags.writeable


def test_bad_inputs():
    with pytest.raises(ParameterError, match="non-decreasing"):
        LightCurve([0.0, 2.0, 1.0], [1.0, 1.0, 1.0])
    with pytest.raises(ParameterError, match="three equal"):
        LightCurve([0.0, 1.0, 1.0, 1.0], [1.0, 1.0, 2.0, 3.0])
    with pytest.raises(ParameterError, match="flux"):
        LightCurve([0.0, 1.0], [1.0, -0.1])
    with pytest.raises(ParameterError, match="flux"):
        LightCurve([0.0, 1.0], [1.0, np.nan])
    with pytest.raises(ParameterError, match="same length"):
        LightCurve([0.0, 1.0], [1.0])
    with pytest.raises(ParameterError, match="ingress"):
        LightCurve.transit(0.0, 10.0, 0.1, 6.0)
    with pytest.raises(ParameterError, match="depth"):
        LightCurve.transit(0.0, 10.0, 1.5, 1.0)
    with pytest.raises(ParameterError, match="decay"):
        LightCurve.flare(0.0, 1.0, 1.0, 0.0)
    lc = LightCurve([0.0], [1.0])
    assert lc.integral(-3.0, 4.0) == 7.0
    with pytest.raises(ParameterError, match="finite"):
        lc.integral(0.0, np.nan)
