"""Validation statistics pooled over realisations, with standard errors.

Each realisation's comparison (:func:`scenesim.validate.compare.compare`) gives,
per true-rate bin, the mean and standard deviation of ``z = (fit - truth) /
sigma_opt`` over its ``n`` pixels, the mean reported chi2 and so on; and the jump
completeness and false-positive rate.  The realisations are independent; the pixels
of one realisation are not (1/f noise, the reference correction and the common mode
are shared along rows and outputs), so errors are taken across realisations, never
from the pixel count.

Pooling uses each realisation's sufficient statistics (``n``, ``n * mean``,
``(n - 1) * std**2 + n * mean**2``, ``n * chi2``, hits flagged, clean pixels
flagged), summed over realisations:

* ``bias`` = pooled mean of ``z`` (``bias_opt`` of one realisation is its bin mean);
* ``scatter`` = pooled standard deviation of ``z``: 1 for an optimal fitter, the
  ``ols_ratio`` ``sqrt(V_ols / V_opt)`` for an equal-weight one; it includes the
  spread of the realisation means, i.e. correlated noise;
* ``scatter_within`` = the same within realisations (each about its own mean:
  the pooled ``std_opt``), and ``scatter_eff`` = the pooled ``std_eff``: the scatter
  against the optimum for the noise the data have (the read noise the fit measured,
  the ADC's rounding), ~1 for a fitter optimal for that noise;
* ``chi2`` = pooled mean of ``z_rep**2`` against the variance the fitter reported
  (1 when its errors are right); ``bias_rep`` likewise;
* ``completeness`` = flagged hits / hits, ``false_positive`` = flagged clean pixels
  / clean pixels, over all realisations.

The standard error of each is the delete-one jackknife over realisations,
``sqrt((K - 1) / K * sum_k (theta_(k) - mean theta_(.))**2)``: for the bias, with
equal ``n`` per realisation, exactly ``std_k(bias_k) / sqrt(K)``; for the jump
rates at least the binomial error ``sqrt(p (1 - p) / n)``, ``p = (k + 1/2) / (n +
1)`` (the jackknife is 0 at a rate of 0 or 1).  The JSON also
gives the pixel-count error ``scatter / sqrt(sum n)`` (``bias_se_pixels``): where
it is much smaller than the jackknife error, the pixels of a realisation share
their noise.
"""

import json
import math
import os

import numpy as np

from noise.errors import ParameterError
from scenesim.batch.manifest import MANIFEST_NAME, read_manifest

__all__ = ["pool_reports", "format_pooled", "jackknife", "pool_directory"]

_NAN = float("nan")


def jackknife(stat, *sums):
    """``(value, standard_error)`` of ``stat`` of per-realisation sums.

    Parameters
    ----------
    stat : callable
        Vectorised function of the totals (arrays broadcast).
    *sums : 1-D arrays, one entry per realisation

    Returns
    -------
    (float, float)
        ``stat`` of the totals, and the delete-one jackknife standard error (NaN
        with fewer than 2 realisations or an undefined statistic).
    """
    sums = [np.asarray(s, dtype=np.float64) for s in sums]
    k = sums[0].size
    totals = [s.sum() for s in sums]
    with np.errstate(divide="ignore", invalid="ignore"):
        value = float(stat(*totals))
        if k < 2:
            return value, _NAN
        loo = np.asarray(stat(*(t - s for t, s in zip(totals, sums))), dtype=np.float64)
    if not np.all(np.isfinite(loo)):
        return value, _NAN
    return value, float(math.sqrt((k - 1) / k * np.sum((loo - loo.mean()) ** 2)))


def _num(row, key):
    v = row.get(key, _NAN)
    return _NAN if v is None else float(v)


def _pool_bin(rows):
    """Pool one bin's rows (one per realisation)."""
    n = np.array([row.get("n", 0) or 0 for row in rows], dtype=np.float64)
    have = n > 0
    out = {"lo": rows[0]["lo"], "hi": rows[0]["hi"], "n_real": int(have.sum()),
           "n_pix": float(n.mean()) if n.size else 0.0}
    keys = ("bias", "bias_se", "scatter", "scatter_se", "scatter_within",
            "scatter_within_se", "scatter_eff", "scatter_eff_se", "chi2", "chi2_se",
            "bias_rep", "bias_rep_se", "ols_ratio", "chi2_fit", "frac_flagged",
            "bias_se_pixels")
    if not have.any():
        out.update({k: _NAN for k in keys})
        return out
    r = [row for row, h in zip(rows, have) if h]
    n = n[have]
    mean = np.array([_num(x, "bias_opt") for x in r])
    std = np.array([_num(x, "std_opt") for x in r])
    std = np.where(np.isfinite(std), std, 0.0)           # one pixel: no spread
    s1 = n * mean
    s2 = (n - 1) * std ** 2 + n * mean ** 2
    chi = n * np.array([_num(x, "chi2_rep") for x in r])
    brep = n * np.array([_num(x, "bias_rep") for x in r])
    out["bias"], out["bias_se"] = jackknife(lambda a, b: b / a, n, s1)
    out["scatter"], out["scatter_se"] = jackknife(
        lambda a, b, c: np.sqrt((c - b * b / a) / (a - 1)), n, s1, s2)
    dof = np.maximum(n - 1, 0)
    out["scatter_within"], out["scatter_within_se"] = jackknife(
        lambda a, b: np.sqrt(b / a), dof, dof * std ** 2)
    eff = np.array([_num(x, "std_eff") for x in r])
    if np.all(np.isfinite(eff) | (n < 2)):
        eff = np.where(np.isfinite(eff), eff, 0.0)
        out["scatter_eff"], out["scatter_eff_se"] = jackknife(
            lambda a, b: np.sqrt(b / a), dof, dof * eff ** 2)
    else:
        out["scatter_eff"] = out["scatter_eff_se"] = _NAN
    out["chi2"], out["chi2_se"] = jackknife(lambda a, b: b / a, n, chi)
    out["bias_rep"], out["bias_rep_se"] = jackknife(lambda a, b: b / a, n, brep)
    for key in ("ols_ratio", "chi2_fit"):
        v = np.array([_num(x, key) for x in r])
        out[key] = float(np.sum(n * v) / n.sum()) if np.all(np.isfinite(v)) else _NAN
    nreg = np.array([x.get("n_regular", 0) or 0 for x in r], dtype=np.float64)
    ff = np.array([_num(x, "frac_flagged") for x in r])
    ok = np.isfinite(ff) & (nreg > 0)
    out["frac_flagged"] = float(np.sum((nreg * ff)[ok]) / nreg[ok].sum()) if ok.any() \
        else _NAN
    out["bias_se_pixels"] = out["scatter"] / math.sqrt(n.sum()) \
        if math.isfinite(out["scatter"]) else _NAN
    return out


def _pool_rate(jumps, count_key, rate_key):
    """Pooled rate (flagged / count) of the jump statistics, with its error."""
    count = np.array([j.get(count_key, 0) or 0 for j in jumps], dtype=np.float64)
    rate = np.array([_num(j, rate_key) for j in jumps])
    flagged = np.where(count > 0, np.round(count * np.nan_to_num(rate)), 0.0)
    if count.sum() == 0:
        return _NAN, _NAN, 0
    value, se = jackknife(lambda a, b: b / a, count, flagged)
    # at 0 or 1 the jackknife is 0 (no realisation moves it), which says nothing:
    # at least the binomial error of a rate taken one count inside the boundary,
    # sqrt(p (1 - p) / n), p = (k + 1/2) / (n + 1) (a probe's 207 hits, all
    # flagged, read "1.0000 +- 0.0000")
    n, k = float(count.sum()), float(flagged.sum())
    p = (k + 0.5) / (n + 1.0)
    se = max(float(se), math.sqrt(p * (1.0 - p) / n))
    return value, se, int(n)


def pool_reports(reports):
    """Pool per-realisation comparisons of one fitter on one scene.

    Parameters
    ----------
    reports : sequence of dict
        Each ``{'rows': [...], 'jumps': {...}, 'photometry': {...}}`` as
        :meth:`scenesim.validate.compare.Report.to_dict` gives them, one per
        realisation, all with the same flux bins.

    Returns
    -------
    dict
        ``n_real``; ``rows`` (per bin: ``lo``, ``hi`` (e-/s), ``n_real``
        (realisations with pixels in the bin), ``n_pix`` (pixels per realisation),
        ``bias``, ``scatter``, ``chi2``, ``bias_rep`` each with ``_se``,
        ``ols_ratio``, ``chi2_fit``, ``frac_flagged``, ``bias_se_pixels``);
        ``jumps`` (``completeness``, ``false_positive`` with ``_se``, ``n_hit``,
        ``n_clean``); ``photometry`` (``median_ratio`` mean over realisations and
        its standard error).
    """
    reports = list(reports)
    out = {"n_real": len(reports), "rows": [], "jumps": {}, "photometry": {}}
    if not reports:
        return out
    bins = {}
    for rep in reports:
        for row in rep.get("rows", []):
            bins.setdefault((row["lo"], row["hi"]), []).append(row)
    out["rows"] = [_pool_bin(rows) for rows in bins.values()]
    jumps = [rep["jumps"] for rep in reports if rep.get("jumps")]
    if jumps:
        c, c_se, n_hit = _pool_rate(jumps, "n_hit", "completeness")
        f, f_se, n_clean = _pool_rate(jumps, "n_clean", "false_positive")
        out["jumps"] = {"completeness": c, "completeness_se": c_se, "n_hit": n_hit,
                        "false_positive": f, "false_positive_se": f_se,
                        "n_clean": n_clean, "n_real": len(jumps)}
    ratios = np.array([_num(rep.get("photometry") or {}, "median_ratio")
                       for rep in reports])
    ratios = ratios[np.isfinite(ratios)]
    if ratios.size:
        se = float(ratios.std(ddof=1) / math.sqrt(ratios.size)) if ratios.size > 1 \
            else _NAN
        out["photometry"] = {"median_ratio": float(ratios.mean()),
                             "median_ratio_se": se, "n_real": int(ratios.size)}
    return out


def _pm(value, se, fmt, sign=""):
    if not math.isfinite(value):
        return "-"
    text = format(value, sign + fmt)
    return text + (f" +- {se:{fmt}}" if math.isfinite(se) else "")


def format_pooled(pooled, *, title):
    """Printable table of one :func:`pool_reports` result under ``title``."""
    lines = [f"{title}: {pooled['n_real']} realisations",
             "  bias, scatter: (fit - truth) / sigma_opt, the optimum in white read "
             "noise (scatter over all realisations);",
             "  eff: scatter within a realisation against the optimum for the noise "
             "measured on the ramps; chi2: against the",
             "  fitter's own variance; +- one standard error across realisations "
             "(jackknife)",
             f"{'rate (e-/s)':>15} {'px/real':>8} {'bias':>18} {'scatter':>17} "
             f"{'eff':>17} {'ols/opt':>7} {'chi2':>15} {'flagged':>8}"]
    for r in pooled["rows"]:
        hi = "inf" if not math.isfinite(r["hi"]) else f"{r['hi']:g}"
        label = f"{r['lo']:g} - {hi}"
        lines.append(
            f"{label:>15} {r['n_pix']:>8.0f} "
            f"{_pm(r['bias'], r['bias_se'], '.4f', '+'):>18} "
            f"{_pm(r['scatter'], r['scatter_se'], '.4f'):>17} "
            f"{_pm(r['scatter_eff'], r['scatter_eff_se'], '.4f'):>17} "
            f"{_pm(r['ols_ratio'], _NAN, '.3f'):>7} "
            f"{_pm(r['chi2'], r['chi2_se'], '.3f'):>15} "
            f"{_pm(r['frac_flagged'], _NAN, '.4f'):>8}")
    j = pooled.get("jumps")
    if j:
        lines.append(f"jumps: completeness {_pm(j['completeness'], j['completeness_se'], '.4f')}"
                     f" of {j['n_hit']} hit pixels; false-positive rate "
                     f"{_pm(j['false_positive'], j['false_positive_se'], '.2e')} of "
                     f"{j['n_clean']} clean pixels")
    p = pooled.get("photometry")
    if p:
        lines.append(f"photometry: measured/injected (median per realisation) "
                     f"{_pm(p['median_ratio'], p['median_ratio_se'], '.4f')}")
    return "\n".join(lines)


def pool_directory(out_dir):
    """Pool the comparisons recorded in the batch directory ``out_dir``.

    Reads the manifest (:mod:`scenesim.batch.manifest`) and the record of every
    finished task of the batch's last run (its ``realisations``: rows kept from an
    earlier run with more are left out, as the batch's own tables leave them).

    Returns
    -------
    (dict, dict)
        The manifest, and ``{point label: {fitter: pool_reports(...)}}``.

    Raises
    ------
    noise.errors.ParameterError
        No manifest in ``out_dir``, or no finished task with a comparison.
    """
    manifest = read_manifest(out_dir, what="'--pool'", advice="give the directory of a "
                             "batch") if os.path.isdir(out_dir) else None
    if manifest is None:
        raise ParameterError(f"'pool': {out_dir!r} holds no scenesim batch manifest "
                             f"({MANIFEST_NAME}); give the --out directory of a batch")
    labels = {p["index"]: p["label"] for p in manifest.get("points", [])}
    # the realisations of the batch's last run, as its own tables pooled them: a run
    # with fewer than an earlier one keeps the earlier rows for a later resume, and
    # pooling them too had printed other tables than the batch's
    upto = manifest.get("realisations")
    by_point = {}
    damaged, done = [], 0
    for name, row in manifest.get("tasks", {}).items():
        if row.get("status") != "done":
            continue
        if isinstance(upto, int) and row.get("realisation", 0) >= upto:
            continue
        done += 1
        try:
            with open(os.path.join(out_dir, row["outputs"]["record"]),
                      encoding="utf-8") as fh:
                rec = json.load(fh)
            if not isinstance(rec, dict):
                raise ValueError("not a record")
        except (OSError, ValueError, KeyError):
            damaged.append(name)       # had been left out without a word
            continue
        for fitter, rep in (rec.get("reports") or {}).items():
            by_point.setdefault(labels.get(row["point"], ""), {}).setdefault(
                fitter, []).append(rep)
    if damaged:
        raise ParameterError(
            f"'pool': the records of {len(damaged)} of the {done} finished tasks in "
            f"{out_dir!r} are missing or damaged ({', '.join(damaged[:5])}"
            f"{', ...' if len(damaged) > 5 else ''}); run the same batch again to "
            f"redo them")
    if not by_point:
        raise ParameterError(f"'pool': no finished task of the batch in {out_dir!r} "
                             f"has a comparison; run the batch with --compare")
    return manifest, {label: {f: pool_reports(reps) for f, reps in per.items()}
                      for label, per in by_point.items()}
