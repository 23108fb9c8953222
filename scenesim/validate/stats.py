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
  ``V_opt = optimal_variance(truth, read_times, read_noise) / nints``, the minimum
  variance of an unbiased linear slope estimate for that readout (Brandt 2024, PASP
  136, 045004, eqs. 28-29; integrations are independent, so their optimal combination
  divides it by ``nints``).  ``std_opt`` = 1 for an optimal fitter; an equal-weight
  fitter reaches ``sqrt(V_ols / V_opt)`` (``ols_ratio``, the bin mean, from
  :func:`scenesim.rampfit.variance.ols_variance`).  Its standard error is about
  ``std_opt / sqrt(2 n)``;
* ``chi2_fit``: mean reported ``CHI2`` (when the file has it);
* ``frac_flagged``: fraction of the bin's regular pixels with any DQ bit set.

"""

import numpy as np


__all__ = ['DEFAULT_EDGES', 'bin_rows']


#: Default flux-bin edges, e-/s (true rate ``RATE_IPC``).
DEFAULT_EDGES = (0.0, 0.01, 0.1, 1.0, 10.0, 100.0, 1e3, 1e4, np.inf)


def bin_rows(fit, rate, var_opt, var_ols, edges, use_mask, regular):
    res = fit["slope"] - rate
    var = fit["var"]
    good = use_mask & np.isfinite(var) & (var > 0) & (var_opt > 0)
    rows = []
    idx = np.digitize(rate, edges[1:-1], right=False)  # bin k: edges[k] <= r < edges[k+1]
    for k in range(len(edges) - 1):
        inbin = idx == k
        reg = regular & inbin
        sel = good & inbin
        n = int(sel.sum())
        row = {"lo": float(edges[k]), "hi": float(edges[k + 1]),
               "n_regular": int(reg.sum()), "n": n}
        nan = float("nan")
        if n:
            z_rep = res[sel] / np.sqrt(var[sel])
            z_opt = res[sel] / np.sqrt(var_opt[sel])
            row.update(bias_rep=float(z_rep.mean()), chi2_rep=float(np.mean(z_rep ** 2)),
                       bias_opt=float(z_opt.mean()),
                       std_opt=float(z_opt.std(ddof=1)) if n > 1 else nan,
                       ols_ratio=float(np.mean(np.sqrt(var_ols[sel] / var_opt[sel]))),
                       chi2_fit=(float(fit["chi2"][sel].mean()) if fit["chi2"] is not None
                                 else nan))
        else:
            row.update(bias_rep=nan, chi2_rep=nan, bias_opt=nan, std_opt=nan,
                       ols_ratio=nan, chi2_fit=nan)
        row["frac_flagged"] = (float(np.mean(fit["dq"][reg] != 0)) if row["n_regular"]
                               else nan)
        rows.append(row)
    return rows
