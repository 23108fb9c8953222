"""Ramps and their exact covariance, built from the read times alone (test helper).

Shared by the tests of :mod:`scenesim.rampfit` and :mod:`scenesim.calib`: the ramps
are simulated here, independently of the simulator (Poisson increments of charge
between consecutive reads at their exact times from reset, Gaussian read noise per
read, reads averaged into resultants), and the reference variances come from a dense
covariance of the resultants computed from the read times themselves
(``Cov(Q(t), Q(t')) = f min(t, t')``), not from the package's formulas.  Read noise is
per read (not CDS), in e-.
"""

import numpy as np

T_JWST = 10.737     # s, H2RG full-frame time
T_ROMAN = 3.04      # s
SIGMA = 10.0        # e- per read
ROMAN_TABLE = ((0, 1), (1, 2), (3, 3), (6, 4), (10, 6), (16, 6), (22, 8), (30, 8),
               (38, 6))


def jwst_times(ngroups=20, nframes=1, groupgap=0, t_frame=T_JWST):
    """Read times of a MULTIACCUM ramp, rolling reset: read k at (k + 1) t_frame."""
    return [(np.arange(nframes) + g * (nframes + groupgap) + 1) * t_frame
            for g in range(ngroups)]


def roman_times(t_frame=T_ROMAN):
    """Uneven 9-resultant / 44-read table."""
    return [(np.arange(a, a + n) + 1) * t_frame for a, n in ROMAN_TABLE]


READOUTS = {"jwst20": jwst_times, "roman9": roman_times}


def simulate(rng, rate, times, sigma, shape, *, nints=None, hits=None, gain=None):
    """Resultants (e-) of constant-rate ramps.

    ``rate`` scalar or array of ``shape``.  ``hits``: optional (time, amplitude) arrays
    of ``shape``: a charge ``amplitude`` arrives at ``time`` (s from reset).
    ``gain`` (e-/DN): digitise every read (``rint((bias + read) / gain)``, ``bias``
    a level per pixel, uniform over 0-1000 e-, so that the rounding's phase differs
    between pixels as on a detector) and store each resultant as the rounded mean of
    its codes, times ``gain``, minus the bias (on-board averaging).
    """
    allt = np.concatenate(times)
    nres = len(times)
    lead = () if nints is None else (nints,)
    out = np.empty(lead + (nres,) + shape, np.float64)
    bias = None if gain is None else rng.uniform(0.0, 1000.0, shape)
    for k in range(1 if nints is None else nints):
        q = np.zeros(shape)
        prev = 0.0
        acc = np.zeros((nres,) + shape)
        r_of_read = np.repeat(np.arange(nres), [len(t) for t in times])
        for t, r in zip(allt, r_of_read):
            q = q + rng.poisson(rate * (t - prev), size=shape)
            read = q + sigma * rng.standard_normal(shape)
            if hits is not None:
                read = read + np.where(hits[0] < t, hits[1], 0.0)
            acc[r] += read if gain is None else np.rint((bias + read) / gain)
            prev = t
        acc /= np.array([len(t) for t in times], float)[(...,) + (None,) * len(shape)]
        if gain is not None:
            acc = np.rint(acc) * gain - bias
        if nints is None:
            out[:] = acc
        else:
            out[k] = acc
    return out


def dense_cov(times, sigma):
    """Read-noise (per sigma^2 = 1 scaled by sigma^2) and Poisson (per unit rate)
    covariance of the resultants, from the read times."""
    n = np.array([len(t) for t in times], float)
    m = np.array([[np.minimum.outer(a, b).mean() for b in times] for a in times])
    return sigma ** 2 * np.diag(1 / n), m


def dense_gls(rate, times, sigma):
    """GLS with free intercept on the dense resultant covariance.

    Returns (variance of the slope, read part, Poisson part per unit rate).
    """
    r, m = dense_cov(times, sigma)
    cov = r + rate * m
    tb = np.array([t.mean() for t in times])
    x = np.stack([np.ones_like(tb), tb], axis=1)
    ci = np.linalg.inv(cov)
    par = np.linalg.inv(x.T @ ci @ x)
    c = (par @ x.T @ ci)[1]
    return par[1, 1], c @ r @ c, c @ m @ c


def dense_ols(rate, times, sigma):
    """Equal-weight least squares on resultants vs mean time: exact c^T Sigma c."""
    r, m = dense_cov(times, sigma)
    tb = np.array([t.mean() for t in times])
    c = (tb - tb.mean()) / np.sum((tb - tb.mean()) ** 2)
    return c @ (r + rate * m) @ c


def expected_z2(rate, times, sigma):
    """E[(f_hat - f)^2 / V_hat] for V_hat = V_read + q_p max(f_hat, 0).

    The reported variance uses the fitted rate (clipped at 0), so it is correlated
    with the error; for f_hat ~ N(f, V_opt) the expectation is a 1-D integral
    (evaluated on a +-12 sigma grid).  It is 1 when q_p sqrt(V) << V, i.e. when one
    sigma of the rate changes the Poisson variance negligibly.
    """
    v, vr, qp = dense_gls(rate, times, sigma)
    s = np.sqrt(v)
    x = rate + s * np.linspace(-12, 12, 48001)
    w = np.exp(-0.5 * ((x - rate) / s) ** 2)
    w /= w.sum()
    return float(np.sum(w * (x - rate) ** 2 / (vr + qp * np.maximum(x, 0))))
