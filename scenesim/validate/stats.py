"""Slope errors per true-rate bin: bias, scatter and chi-square.

Pixels are binned by their true rate ``RATE_IPC`` (e-/s, after IPC: what a
linear ramp fit should recover; ``RATE`` if absent), in log bins
(:data:`DEFAULT_EDGES`).  Reference pixels are left out; the statistics use the pixels
not flagged ``DO_NOT_USE``.  For each bin, with ``r = fit - truth``:

* ``bias_rep = mean(r / sqrt(V_rep))`` and ``chi2_rep = mean(r^2 / V_rep)``, with
  ``V_rep`` the variance the fitter reported: ``chi2_rep`` ~ 1 when the reported errors
  are right, ``bias_rep`` ~ 0 when the fit is unbiased (standard error
  ``1/sqrt(n)``);
* ``bias_opt = mean(r / sqrt(V_opt))`` and ``std_opt = std(r / sqrt(V_opt))`` with
  ``V_opt`` the minimum variance of an unbiased linear slope estimate for the readout
  with white read noise alone (the header's ``RDNOISE``; Brandt 2024, PASP 136,
  045004, eqs. 28-29), over each pixel's *usable* ramp: up to its first saturated
  resultant (truth ``SATGROUP``), integrations combined (their inverse variances
  add; :func:`usable_variance`).  ``std_opt`` = 1 for an optimal fitter in white
  noise; an equal-weight fitter reaches ``sqrt(V_ols / V_opt)`` (``ols_ratio``, the
  bin mean, from :func:`scenesim.rampfit.variance.ols_variance`).  Its standard error
  is about ``std_opt / sqrt(2 n)``;
* ``se_bias``: the standard error of ``bias_opt``, cluster-robust
  (:func:`cluster_se`): the pixels of one output and one band of 16 rows share
  correlated noise, so a bin's mean error is an average of cluster draws, not of
  ``n`` independent ones; ``n_cl`` is their number, and ``p_bias`` the two-sided
  p-value of ``bias_opt / se_bias`` under Student's t with ``dof_bias`` degrees of
  freedom (at most ``n_cl - 1``, :func:`cluster_dof`: a bin of a few stars holds a
  few clusters, and there a normal law's 3 sigma is not rare); none below 2 of
  them (:func:`bias_p_value`).  With unequal clusters it is conservative for
  independent pixels (clusters of 30, 2, 1, 1, 1: p < 0.05 in 1 % of null draws).  It cannot include an error common to the whole array (the
  part of the correlated 1/f noise that the reference correction and the common-mode
  removal leave in every pixel's slope): one exposure holds one draw of it.  On
  ``scenes/quick.toml`` that part dominates (``docs/VALIDATION_COMPARE.md``): pooling
  realisations measures a bias to that level;
* ``std_eff = std(r / sqrt(V_eff))``: as ``std_opt`` against the optimum for the
  noise the data actually have: the read noise the fit measured on the ramps (its
  ``RNOISE``, which contains every white per-read term: read noise, the ADC's
  ``gain^2 / 12`` and what the corrections left of the correlated noise; without it
  the model's ``RDNOISE`` with ``gain^2 / 12`` added), plus the rounding of each
  on-board average of ``N > 1`` reads, ``gain^2 / 12 (1 - 1/N^2)`` per resultant
  for odd ``N``, ``gain^2 / 12 (1 + 2/N^2)`` for even (:func:`noise.adc.averaging_noise`).
  With correlated (1/f) noise ``std_opt`` exceeds 1 even for an optimal fitter;
  ``std_eff`` ~ 1 says the fitter is optimal for the noise it was given;
* ``chi2_fit``: mean reported ``CHI2`` (when the file has it);
* ``frac_flagged``: fraction of the bin's regular pixels with any DQ bit set.
"""

import numpy as np

from scenesim.rampfit import optimal_variance


__all__ = ["DEFAULT_EDGES", "bin_rows", "usable_variance", "cluster_se", "cluster_dof",
           "bias_p_value"]


#: Default flux-bin edges, e-/s (true rate ``RATE_IPC``).
DEFAULT_EDGES = (0.0, 0.01, 0.1, 1.0, 10.0, 100.0, 1e3, 1e4, np.inf)


def usable_variance(rate, read_times, read_noise, *, nints, satgroup=None,
                    resultant_noise=0.0, variance=optimal_variance):
    """Per-pixel theoretical slope variance over each pixel's usable ramp.

    Each integration's ramp is usable up to its first saturated resultant (truth
    ``SATGROUP``; all resultants where it is -1 or absent); integrations are
    independent, so their inverse variances add.  Pixels with fewer than two usable
    resultants in every integration have no slope: ``inf``.

    Parameters
    ----------
    rate : ndarray (ny, nx), e-/s, >= 0
    read_times : list of 1-D arrays, s
    read_noise : float, e- per read (not CDS)
    nints : int
    satgroup : ndarray (nints, ny, nx) or (ny, nx) int, or None
    resultant_noise : float or sequence, e- rms per resultant (see
        :func:`scenesim.rampfit.optimal_variance`); used with ``optimal_variance``
    variance : callable
        :func:`scenesim.rampfit.optimal_variance` or
        :func:`scenesim.rampfit.ols_variance`.
    """
    ng = len(read_times)
    kw = {} if variance is not optimal_variance else {"resultant_noise": resultant_noise}
    q = np.broadcast_to(np.asarray(resultant_noise, dtype=np.float64), (ng,))
    if satgroup is None:
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.asarray(variance(rate, read_times, read_noise, **kw)) / nints
    sat = np.asarray(satgroup)
    if sat.ndim == 2:
        sat = np.broadcast_to(sat, (nints,) + sat.shape)
    inv = np.zeros(rate.shape)
    for i in range(nints):
        usable = np.where(sat[i] >= 0, sat[i], ng)
        for m in np.unique(usable):
            if m < 2:
                continue
            sel = usable == m
            if variance is optimal_variance:
                kw = {"resultant_noise": q[:m]}
            with np.errstate(divide="ignore", invalid="ignore"):
                v = np.asarray(variance(rate[sel], read_times[:m], read_noise, **kw))
                inv[sel] += 1.0 / v
    with np.errstate(divide="ignore"):
        return np.where(inv > 0, 1.0 / inv, np.inf)


def cluster_se(z, labels):
    """Standard error of ``mean(z)`` when values sharing a label are correlated.

    The cluster-robust (sandwich) estimate with the small-sample correction of Bell
    and McCaffrey (2002, "CR2"): ``sqrt(sum_b S_b^2 / (1 - n_b / n)) / n``, ``S_b``
    the sum of ``z - mean`` over cluster ``b`` of ``n_b`` values.  Correlated noise
    common to a cluster (1/f noise shared by the pixels of an output read close in
    time) makes the bin mean one draw per cluster, not one per pixel.  For
    independent values of one variance the estimate of the variance is unbiased
    whatever the cluster sizes (``E[S_b^2] = sigma^2 n_b (1 - n_b / n)``); with one
    pixel per cluster it is the usual ``std / sqrt(n)``.  (The ``B / (B - 1)`` form
    used before was biased low for few, unequal clusters: a probe's bins of 3-7
    clusters read ``|bias / se| > 3`` 13-40 times too often.)  With ``B`` clusters the
    ratio ``mean / se`` follows Student's t with at most ``B - 1`` degrees of freedom
    (:func:`cluster_dof`), not a normal law (:func:`bias_p_value`).
    """
    n = z.size
    dev = z - z.mean()
    _, inverse = np.unique(labels, return_inverse=True)
    sums = np.bincount(inverse, weights=dev)
    sizes = np.bincount(inverse)
    if sums.size < 2:
        return float("nan")
    return float(np.sqrt(np.sum(sums ** 2 / (1.0 - sizes / n))) / n)


def cluster_dof(labels):
    """Degrees of freedom of :func:`cluster_se` (Satterthwaite, as Bell and McCaffrey
    2002): ``(tr M)^2 / tr(M^2)``, ``M`` the estimate's quadratic form on the cluster
    sums times their covariance for independent values of one variance.  ``B - 1``
    for ``B`` clusters of equal size, fewer when a few clusters hold most values;
    NaN below 2 clusters."""
    _, sizes = np.unique(labels, return_counts=True)
    if sizes.size < 2:
        return float("nan")
    nb = sizes.astype(float)
    n = nb.sum()
    w = 1.0 / (1.0 - nb / n)               # the n^-2 of every weight cancels
    diag = nb * (1.0 - nb / n)             # Var(S_b) / sigma^2
    tr = np.sum(w * diag)
    a = w * nb * nb
    tr2 = np.sum((w * diag) ** 2) + (a.sum() ** 2 - np.sum(a * a)) / n ** 2
    return float(tr * tr / tr2)


#: Fewer effective degrees of freedom than this: no p-value (:func:`bias_p_value`).
MIN_DOF = 2.0


def bias_p_value(bias, se, dof):
    """Two-sided p-value of ``bias / se`` under Student's t with ``dof`` degrees of
    freedom (:func:`cluster_dof`): the chance of a bias at least this large from
    noise alone.  NaN when undefined (no error) and below :data:`MIN_DOF`: a bin
    whose pixels are nearly all in one or two clusters (a bright star's band and a
    few stray pixels) holds one or two draws of the correlated noise, and no test
    of its bias is calibrated (a probe: clusters of 100, 1 and 1 pixels, dof 1.02,
    gave p < 0.05 in 12-19 % of null draws; of 10, 10 and 10, dof 2, in 5.05 %)."""
    from scipy.stats import t as student_t
    if not (np.isfinite(dof) and dof >= MIN_DOF and np.isfinite(se) and se > 0
            and np.isfinite(bias)):
        return float("nan")
    return float(2.0 * student_t.sf(abs(bias) / se, dof))


def bin_rows(fit, rate, var_opt, var_eff, var_ols, edges, use_mask, regular,
             clusters=None):
    """Per true-rate bin statistics (module notes); ``clusters`` labels the pixels
    whose noise is correlated (for the standard error of the bias), None: every
    pixel its own."""
    res = fit["slope"] - rate
    var = fit["var"]
    good = (use_mask & np.isfinite(var) & (var > 0) & (var_opt > 0)
            & np.isfinite(var_opt))
    if clusters is None:
        clusters = np.arange(rate.size).reshape(rate.shape)
    rows = []
    idx = np.digitize(rate, edges[1:-1], right=False)  # bin k: edges[k] <= r < edges[k+1]
    nan = float("nan")
    for k in range(len(edges) - 1):
        inbin = idx == k
        reg = regular & inbin
        sel = good & inbin
        n = int(sel.sum())
        row = {"lo": float(edges[k]), "hi": float(edges[k + 1]),
               "n_regular": int(reg.sum()), "n": n}
        if n:
            z_rep = res[sel] / np.sqrt(var[sel])
            z_opt = res[sel] / np.sqrt(var_opt[sel])
            z_eff = res[sel] / np.sqrt(var_eff[sel])
            lab = clusters[sel]
            se = cluster_se(z_opt, lab) if n > 1 else nan
            dof = cluster_dof(lab)
            row.update(bias_rep=float(z_rep.mean()), chi2_rep=float(np.mean(z_rep ** 2)),
                       bias_opt=float(z_opt.mean()), se_bias=se,
                       n_cl=int(np.unique(lab).size), dof_bias=dof,
                       p_bias=bias_p_value(float(z_opt.mean()), se, dof),
                       std_opt=float(z_opt.std(ddof=1)) if n > 1 else nan,
                       std_eff=float(z_eff.std(ddof=1)) if n > 1 else nan,
                       ols_ratio=float(np.mean(np.sqrt(var_ols[sel] / var_opt[sel]))),
                       chi2_fit=(float(fit["chi2"][sel].mean()) if fit["chi2"] is not None
                                 else nan))
        else:
            row.update(bias_rep=nan, chi2_rep=nan, bias_opt=nan, se_bias=nan, n_cl=0,
                       dof_bias=nan, p_bias=nan,
                       std_opt=nan, std_eff=nan, ols_ratio=nan, chi2_fit=nan)
        row["frac_flagged"] = (float(np.mean(fit["dq"][reg] != 0)) if row["n_regular"]
                               else nan)
        rows.append(row)
    return rows
