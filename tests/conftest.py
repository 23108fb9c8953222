"""Shared fixtures for the noise tests: averaged periodograms and 1/f theory.

The helpers are independent of :mod:`noise`: they implement the textbook estimators and
the amplitude definition of ``noise.params`` from scratch, so the tests compare the
generator with theory rather than with itself.
"""

import numpy as np
import pytest


def _welch(x, nperseg, rate):
    """Averaged one-sided periodogram of ``x`` (Hann window, no overlap, mean removed).

    Parameters
    ----------
    x : array_like, shape (..., n)
        Time series; the last axis is time.  Leading axes are kept.
    nperseg : int
        Samples per segment.
    rate : float
        Sample rate, Hz.

    Returns
    -------
    f : ndarray, shape (nperseg // 2 + 1,), Hz
    psd : ndarray, shape (..., nperseg // 2 + 1), units of x**2 / Hz
        Mean over the ``K`` segments of ``2 |DFT(w x)|^2 / (rate * sum(w^2))``.
    K : int
        Number of averaged segments.  For a Gaussian process each bin of ``psd`` is a
        mean of ``K`` exponential variates: relative standard deviation ``1/sqrt(K)``.
    """
    x = np.asarray(x, dtype=np.float64)
    K = x.shape[-1] // nperseg
    seg = x[..., :K * nperseg].reshape(x.shape[:-1] + (K, nperseg))
    seg = seg - seg.mean(axis=-1, keepdims=True)
    w = np.hanning(nperseg)
    spec = np.fft.rfft(seg * w, axis=-1)
    psd = 2.0 / (rate * np.sum(w ** 2)) * (spec.real ** 2 + spec.imag ** 2)
    f = np.fft.rfftfreq(nperseg, 1.0 / rate)
    return f, psd.mean(axis=-2), K


def _pink_level(amp, rate, n, f_min):
    """Level ``c`` of the PSD ``c / max(f, f_min)`` whose amplitude is ``amp``.

    The amplitude definition of ``noise.params``: ``amp**2`` is the expected variance
    over one frame of ``n`` samples with the frame mean removed,
    ``amp**2 = integral_0^{rate/2} S(f) (1 - F_n(f)) df`` with ``F_n`` the Fejer kernel
    ``[sin(pi f n / rate) / (n sin(pi f / rate))]**2``.  Integrated here on a fine log
    grid, for the ideal spectrum (not the synthesised one).
    """
    f = np.geomspace(f_min * 1e-5, rate / 2, 400001)
    x = np.pi * f / rate
    fejer = (np.sin(n * x) / (n * np.sin(x))) ** 2
    integral = np.trapezoid((1.0 - fejer) / np.maximum(f, f_min), f)
    return amp ** 2 / integral


def _spaced_bins(lo, hi, num):
    """About ``num`` log-spaced DFT bin indices in [lo, hi], at least 2 bins apart.

    With a Hann window the DFT values of bins two apart have correlation 1/6, so their
    periodogram values have correlation 1/36: the selected bins are treated as
    independent.
    """
    idx = np.unique(np.geomspace(lo, hi, num).astype(int))
    keep = [idx[0]]
    for i in idx[1:]:
        if i - keep[-1] >= 2:
            keep.append(i)
    return np.array(keep)


def _fit_loglog(f, psd, K):
    """Least-squares slope of log10(psd) against log10(f), and its standard error.

    Each bin is a mean of ``K`` periodograms, so log10 of it has standard deviation
    ``log10(e) / sqrt(K)`` (first order; the bias ``-1/(2K)`` is the same in every bin
    and does not change the slope).  For independent bins the slope's standard error is
    ``sigma_b / sqrt(sum (x - mean x)^2)``.
    """
    x = np.log10(f)
    y = np.log10(psd)
    xm = x - x.mean()
    slope = np.sum(xm * (y - y.mean())) / np.sum(xm ** 2)
    sigma = np.log10(np.e) / np.sqrt(K) / np.sqrt(np.sum(xm ** 2))
    return slope, sigma


def _corr_sigma(x, y, maxlag=64):
    """Standard deviation of the correlation coefficient of two independent series.

    Bartlett's formula: ``Var(r) = (1 + 2 sum_k rho_x(k) rho_y(k)) / n`` for
    independent stationary series with autocorrelations ``rho_x``, ``rho_y`` (estimated
    here from the data up to ``maxlag``).
    """
    x = np.asarray(x, dtype=np.float64) - np.mean(x)
    y = np.asarray(y, dtype=np.float64) - np.mean(y)
    n = x.size

    def acf(z):
        lags = range(1, maxlag + 1)
        return np.array([np.dot(z[:-k], z[k:]) for k in lags]) / np.dot(z, z)

    return np.sqrt((1.0 + 2.0 * np.sum(acf(x) * acf(y))) / n)


@pytest.fixture
def corr_sigma():
    """Standard deviation of a correlation coefficient, :func:`_corr_sigma`."""
    return _corr_sigma


@pytest.fixture
def welch():
    """The averaged-periodogram estimator :func:`_welch`."""
    return _welch


@pytest.fixture
def pink_level():
    """The 1/f PSD level implied by an amplitude, :func:`_pink_level`."""
    return _pink_level


@pytest.fixture
def spaced_bins():
    """Independent log-spaced bin indices, :func:`_spaced_bins`."""
    return _spaced_bins


@pytest.fixture
def fit_loglog():
    """Log-log slope fit with its standard error, :func:`_fit_loglog`."""
    return _fit_loglog


def pytest_collection_modifyitems(config, items):
    """Run the tests marked ``leaves_threads`` last.

    A dask.distributed client leaves process-wide threads behind (its IO loop and
    offload executor) that live until the interpreter exits.  With other threads
    running, :func:`noise.fast.producer.available` rightly refuses to fork, so the
    tests that check the forked producer in this process must run before them.
    """
    items.sort(key=lambda item: item.get_closest_marker("leaves_threads") is not None)
