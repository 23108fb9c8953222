"""Measuring what a reference-pixel correction removes from, and adds to, the noise.

A study harness around :func:`scenesim.calib.refpix.correct_reference`: closed forms
of the white noise each scheme adds (:func:`white_noise_added`), a measurement on
noise-only ramps from :mod:`noise`, one component at a time
(:func:`measure_reference_correction`), the pooling of several runs
(:func:`pool_measurements`) and a Markdown table (:func:`format_measurement`).  The
results are discussed in ``docs/REFPIX.md``; the measured numbers are in
``docs/VALIDATION_FIT.md``.

White noise added (closed forms, :func:`white_noise_added`)
-----------------------------------------------------------
A reference estimate ``e`` is built from reference pixels only, so it is independent
of a regular pixel's own white noise and adds ``Var(e)`` to every read; in a CDS
difference (or any slope) the added variance relative to the pixel's white variance
``sigma**2`` is the same fraction ``Var(e) / sigma**2``.  With reference-pixel white
noise ``sigma_r = ref_ratio * sigma``:

* median of ``n`` reference-row pixels per output (``n = 2 b ncols_out`` for a full
  frame): ``Var(e) = (pi / 2) sigma_r**2 / n`` (asymptotic; relative error O(1/n)).
  Full H2RG: ``n = 4096``, added fraction ``0.64 pi / 8192 = 2.45e-4``.
* jwst, step 1: a clipped mean of ``n_p`` pixels (``n_p = b ncols_out / 2`` per half
  and parity; top and bottom halves averaged) has ``Var = c sigma_r**2 / n_p`` per
  half, so ``Var(m) = c sigma_r**2 / (b ncols_out)`` (2048 pixels on an H2RG); ``c``
  is the asymptotic variance factor of a mean clipped at ``+-k sigma`` around the
  sample median,
  ``c = [1 - 2Q - 2k phi + 4 k phi sqrt(pi/2) (2 phi(0) - 2 phi) + (pi/2)(2 k phi)**2]
  / (1 - 2Q)**2`` (influence function of the clipped mean plus that of the median
  centre; ``Q`` and ``phi`` the normal tail and density at ``k``), evaluated at the
  fixed point ``k`` of the iterated clip (std of the kept values shrinks the
  threshold from 3 to 2.955): ``c = 1.034`` for ``sigma = 3``.
* jwst, step 2: the row average of ``n_s = 2 b`` side pixels smoothed over ``W`` rows,
  ``Var = sigma_r**2 / (n_s W)``; it carries step 1's estimates of the side pixels'
  outputs, ``M = sum_h w_h m_h`` (``w_h``: share of side pixels in output/parity group
  ``h``), so a pixel of group ``g`` receives ``sum_h (delta_gh - w_h) m_h + s_y`` with
  variance ``sum_h (delta_gh - w_h)**2 Var(m_h) + sigma_r**2 / (n_s W_eff(y))`` plus a
  small covariance from the corner pixels that belong to both (included; < 0.5 %).
  Averaged over the outputs of a 4-output array the step-1 factor is ``(2 * 5/4 + 2 *
  3/4) / 4 = 1``.  Full H2RG, ``W = 11``: ``0.64 (1.034 / 2048 + 1 / 88) = 7.6e-3``.

With kTC in the reference pixels (a spread ``tau`` that is constant over the frames of
an integration), the median picks different pixels from frame to frame and its
frame-to-frame variance grows to ``2 pi (sigma_r**2 + tau**2) [1/4 + arcsin(rho) /
(2 pi)] / n`` with ``rho = -tau**2 / (sigma_r**2 + tau**2)`` (``sqrt(2) sigma_r tau / n``
for ``tau >> sigma_r``): 6.4x the white-only value for NIRSpec (``tau = 29``), still
1.6e-3 of the white variance.  The clipped mean is nearly linear and barely affected.

Measurement (:func:`measure_reference_correction`)
--------------------------------------------------
Each noise component of :mod:`noise` is generated alone (all other amplitudes zero,
the same root seed, so the ``'all'`` ramp is the sum of the single-component ramps),
every frame is corrected, and the statistics are taken on the regular pixels of the
``nframes - 1`` consecutive frame differences ``D`` (CDS pairs), before and after
correction: ``var = <D**2>`` (mean over pixels and pairs, e-**2).  kTC and the bias
are constant over an integration and cancel exactly in ``D``; for ``'all'`` the known
bias (offset + pattern) is subtracted before correcting, as the pipeline's superbias
step does, and the kTC of the integration stays in the frames.

The *targeted* part of ``D`` is what an ideal correction of the same form would remove
if it could read the regular pixels themselves: for ``'median'`` the mean of ``D``
over each output's regular pixels; for ``'jwst'`` the mean over each output's regular
even and odd columns, plus the running mean over the same ``W`` rows of the row means
of the remainder.  ``var_targeted = <D**2> - <(D - T)**2>``.
"""

import math

import numpy as np

from noise.errors import ParameterError
from noise.generator import NoiseGenerator
from noise.params import NIRSPEC_DEFAULTS, NoiseParams
from noise.streams import root_seed
from noise.validate import check_int

from scenesim.calib.refpix import (check_correction_options,
                                   clipped_mean_variance_factor, correct_reference,
                                   reference_edges, running_mean, window_bounds)

__all__ = ["MEASURED_COMPONENTS", "white_noise_added", "measure_reference_correction",
           "pool_measurements", "format_measurement"]

#: Components :func:`measure_reference_correction` can isolate, plus ``'all'``.
MEASURED_COMPONENTS = ("pedestal", "c_pink", "u_pink", "acn", "pca0", "white", "all")

# Amplitudes switched off to isolate one component.
_OFF = dict(rd_noise=0.0, c_pink=0.0, u_pink=0.0, acn=0.0, pca0=0.0, pedestal=0.0,
            ktc=0.0, bias_offset=0.0, bias_amp=0.0, rtn_fraction=0.0)


def white_noise_added(detector, params=NIRSPEC_DEFAULTS, *, scheme="jwst", side_window=11,
                      sigma=3.0):
    """Closed-form white-noise variance a correction adds, relative to the pixels' own.

    Parameters
    ----------
    detector : noise.clock.Detector
    params : noise.params.NoiseParams
        Only ``rd_noise`` (per read, e-, scalar or per output) and ``ref_ratio`` are
        used: white noise alone, no kTC or bias in the reference pixels (see the
        module notes for the median with kTC).
    scheme, side_window, sigma
        As in :func:`correct_reference`.

    Returns
    -------
    float
        ``mean Var(e) / mean sigma**2`` over the regular pixels (dimensionless): the
        fractional increase of the white variance of every read, and so of a CDS
        difference.  Formulas in the module notes.
    """
    check_correction_options(detector, scheme, side_window, sigma)
    if not isinstance(params, NoiseParams):
        raise ParameterError(
            f"'params' must be a noise.params.NoiseParams, got {type(params).__name__}")
    ny, nx = detector.shape
    nout, ncol = detector.n_out_active, detector.ncols_out
    reg = _regular(detector)
    col_out = detector.output_of_column()
    rd2 = params.per_output("rd_noise", nout) ** 2               # (nout,) e-^2
    sr2 = params.ref_ratio ** 2 * rd2
    nreg_col = reg.sum(axis=0)                                   # regular pixels per column
    sig2 = np.sum(nreg_col * rd2[col_out]) / nreg_col.sum()
    if scheme == "none" or sig2 == 0:
        return 0.0
    bottom, top, side = reference_edges(detector)
    if scheme == "median":
        n_out = (bottom.size + top.size) * ncol
        var_col = (math.pi / 2) * sr2[col_out] / n_out
        return float(np.sum(nreg_col * var_col) / nreg_col.sum() / sig2)

    ngrp = 2 * nout
    group = 2 * col_out + (np.arange(nx) % ncol) % 2             # output/parity of a column
    var = _jwst_variance(ny, sr2, group, ngrp, (bottom, top, side), side_window, sigma)
    onehot = (group[:, None] == np.arange(ngrp)[None, :]).astype(float)
    counts = reg.astype(float) @ onehot                          # (ny, G) regular pixels
    return float(np.sum(counts * var) / counts.sum() / sig2)


def _jwst_variance(ny, sr2, group, ngrp, edges, side_window, sigma):
    """``Var(e)`` (ny, G) of the ``'jwst'`` estimate per row and output/parity group.

    ``sr2`` (nout,) reference-pixel white variance per output, ``group`` (nx,) the
    group of every column, ``edges`` the bottom rows, top rows and side columns
    (:func:`scenesim.calib.refpix.reference_edges`); formulas in the module notes.
    """
    bottom, top, side = edges
    grp_out = np.arange(ngrp) // 2
    ncols_g = np.bincount(group, minlength=ngrp)                 # columns per group
    halves = [h for h in (bottom, top) if h.size]
    var = np.zeros((ny, ngrp))                                   # Var(e) per row and group
    alpha = np.zeros((ngrp, ngrp))
    if halves:
        c = clipped_mean_variance_factor(sigma)
        inv = np.divide(1.0, ncols_g, out=np.zeros(ngrp), where=ncols_g > 0)
        v_m = c * sr2[grp_out] * inv * sum(1.0 / h.size for h in halves) \
            / len(halves) ** 2                                   # (G,) Var(m_h)
        w = np.zeros(ngrp)
        if side.size:
            w = np.bincount(group[side], minlength=ngrp) / side.size
        alpha = np.eye(ngrp) - w[None, :]
        var += ((alpha ** 2) * v_m[None, :]).sum(axis=1)[None, :]
    if side.size:
        lo, hi = window_bounds(ny, side_window)
        weff = (hi - lo).astype(float)
        s2 = np.sum(sr2[group[side] // 2]) / side.size ** 2      # one row's side mean
        var += (s2 / weff)[:, None]
        if halves:
            # Corner pixels are in both m_h and the side rows of the window.
            k_h = np.bincount(group[side], minlength=ngrp)       # side columns per group
            cov = np.zeros((ny, ngrp))                           # Cov(m_h, s_y)
            for h in halves:
                inside = (h[None, :] >= lo[:, None]) & (h[None, :] < hi[:, None])
                n_in = inside.sum(axis=1)                        # rows of h in window(y)
                cov += n_in[:, None] * (sr2[grp_out] * k_h * inv
                                        / (len(halves) * h.size))[None, :]
            cov /= (side.size * weff)[:, None]
            var += 2 * cov @ alpha.T
    return var


def _regular(detector):
    """Regular-pixel mask of the readout; raise if it has none."""
    reg = ~detector.reference_mask()
    if not reg.any():
        raise ParameterError(
            f"readout {detector.subarray_name!r} of detector {detector.name!r} has only "
            f"reference pixels; the measurement needs regular pixels")
    return reg


def _isolate(params, name):
    """``params`` with only component ``name`` on, or None if it is off in ``params``."""
    if name == "all":
        return params
    keep = "rd_noise" if name == "white" else name
    p = params.replace(**{k: v for k, v in _OFF.items() if k != keep})
    return p if p.enabled(keep) else None


class _Oracle:
    """The part of a difference image an ideal correction of the scheme's form removes."""

    def __init__(self, detector, scheme, side_window):
        bottom, top, side = reference_edges(detector)
        ncol = detector.ncols_out
        col_out = detector.output_of_column()
        self.reg = ~detector.reference_mask()
        self.scheme = scheme
        self.window = side_window
        self.group = None
        if scheme == "median":
            self.group = col_out
        elif scheme == "jwst" and (bottom.size or top.size):
            self.group = 2 * col_out + (np.arange(detector.nx) % ncol) % 2
        self.rows = scheme == "jwst" and side.size > 0
        if self.group is not None:
            self.cnt = np.bincount(self.group, weights=self.reg.sum(axis=0))
        self.nrow = self.reg.sum(axis=1)

    def __call__(self, d):
        t = np.zeros_like(d)
        if self.scheme == "none":
            return t
        if self.group is not None:
            s = np.bincount(self.group, weights=np.where(self.reg, d, 0.0).sum(axis=0),
                            minlength=self.cnt.size)
            o = np.divide(s, self.cnt, out=np.zeros_like(s), where=self.cnt > 0)
            t += o[self.group][None, :]
        if self.rows:
            ok = self.nrow > 0
            r = np.where(self.reg, d - t, 0.0).sum(axis=1) / np.maximum(self.nrow, 1)
            num = running_mean(r * ok, self.window)
            den = running_mean(ok.astype(float), self.window)
            t += np.divide(num, den, out=np.zeros_like(num), where=den > 0)[:, None]
        return t


def measure_reference_correction(detector, params=NIRSPEC_DEFAULTS, *, scheme="jwst",
                                 nframes=5, rng=None, side_window=11, sigma=3.0,
                                 components=MEASURED_COMPONENTS, threads=None):
    """Measure what a reference correction removes from, and adds to, noise-only ramps.

    Each component is generated alone with its amplitude from ``params`` (others
    zero), ``nframes`` reads of one integration, every frame corrected with
    :func:`correct_reference`; statistics are over the regular pixels of the
    ``nframes - 1`` consecutive frame differences (CDS pairs).  See the module notes.

    Parameters
    ----------
    detector : noise.clock.Detector
    params : noise.params.NoiseParams
        Amplitudes (e-); default the paper's NIRSpec values.
    scheme : {'jwst', 'median', 'none'}
    nframes : int
        Reads per component (>= 2).
    rng : int, SeedSequence, Generator or None
        Root seed, the same for every component (the streams of :mod:`noise` are
        per component, so ``'all'`` is the sum of the single components).
    side_window, sigma
        As in :func:`correct_reference`.
    components : sequence of str
        Subset of :data:`MEASURED_COMPONENTS`.  ``'white'`` is the white read noise,
        ``'all'`` every component of ``params`` together (kTC, bias and RTN included).
        Components whose amplitude is zero in ``params`` are skipped.
    threads : int, optional
        Threads of the noise generator (results do not depend on it).

    Returns
    -------
    dict
        ``scheme``, ``side_window``, ``sigma``, ``nframes``, ``shape``, ``entropy``
        (root seed entropy, to repeat the run) and ``components``: per component a
        dict with

        ``var_before``, ``var_after``
            ``<D**2>`` over regular pixels and pairs, before and after, e-**2.
        ``removed``
            ``1 - var_after / var_before``.
        ``var_targeted``, ``removed_of_targeted``
            Variance of the part an ideal correction of the same form removes (module
            notes) and ``(var_before - var_after) / var_targeted`` (not for
            ``'white'``).
        ``added``, ``added_theory`` (``'white'`` only)
            ``var_after / var_before - 1`` and :func:`white_noise_added`.
        ``removed_of_correlated`` (``'all'`` with ``'white'`` measured)
            ``(var_before - var_after) / (var_before - var_before['white'])``: the
            net reduction as a share of the correlated (non-white) variance.

    Raises
    ------
    noise.errors.ParameterError
        For bad options, before any frame is generated.
    """
    components = _check_measure_args(detector, params, scheme, nframes, side_window,
                                     sigma, components, threads)
    entropy, key = root_seed(rng)
    seed = np.random.SeedSequence(entropy, spawn_key=key)
    oracle = _Oracle(detector, scheme, side_window)
    settings = dict(scheme=scheme, side_window=side_window, sigma=sigma)
    results = {}
    for name in components:
        p = _isolate(params, name)
        if p is not None:
            results[name] = _measure_component(detector, p, name, seed, nframes, threads,
                                               oracle, settings)
    if "all" in results and "white" in results:
        a, w = results["all"], results["white"]
        corr = a["var_before"] - w["var_before"]
        a["removed_of_correlated"] = (a["var_before"] - a["var_after"]) / corr \
            if corr > 0 else float("nan")
    return dict(scheme=scheme, side_window=int(side_window), sigma=float(sigma),
                nframes=int(nframes), shape=detector.shape, entropy=entropy,
                components=results)


def _check_measure_args(detector, params, scheme, nframes, side_window, sigma,
                        components, threads):
    """Validate :func:`measure_reference_correction`'s options; return the components."""
    check_correction_options(detector, scheme, side_window, sigma)
    if not isinstance(params, NoiseParams):
        raise ParameterError(
            f"'params' must be a noise.params.NoiseParams, got {type(params).__name__}")
    check_int("nframes", nframes, minimum=2)
    if isinstance(components, str):
        components = (components,)
    components = tuple(components)
    bad = [c for c in components if c not in MEASURED_COMPONENTS]
    if bad or not components:
        raise ParameterError(
            f"'components' must be a non-empty subset of {list(MEASURED_COMPONENTS)}, "
            f"got {list(components)!r}")
    if threads is not None:
        check_int("threads", threads, minimum=1)
    _regular(detector)
    for name in components:                      # validates per-output amplitudes
        p = _isolate(params, name)
        if p is not None:
            for amp in ("rd_noise", "u_pink", "acn"):
                p.per_output(amp, detector.n_out_active)
    return components


def _measure_component(detector, p, name, seed, nframes, threads, oracle, settings):
    """Statistics of one component's CDS pairs before and after the correction."""
    reg = oracle.reg
    bias = 0.0
    if name == "all" and (p.bias_offset != 0 or p.bias_amp > 0):
        # the known bias (superbias); kTC of the integration stays in the frames
        bias = NoiseGenerator(detector, p.replace(**{k: v for k, v in _OFF.items()
                                                     if k not in ("bias_offset",
                                                                  "bias_amp")}),
                              rng=0, threads=1).reset_level(0).astype(np.float64)
    gen = NoiseGenerator(detector, p, rng=seed, threads=threads)
    before = after = resid = 0.0
    prev = prev_c = None
    for _, _, frame in gen.frames(nframes):
        f = frame.astype(np.float64) - bias
        c = correct_reference(f, detector, **settings)
        if prev is not None:
            d = f - prev
            before += np.sum(d[reg] ** 2)
            after += np.sum((c - prev_c)[reg] ** 2)
            if name != "white":
                resid += np.sum((d - oracle(d))[reg] ** 2)
        prev, prev_c = f, c
    n = int(reg.sum()) * (nframes - 1)
    vb, va = before / n, after / n
    res = dict(var_before=vb, var_after=va, removed=1 - va / vb if vb > 0 else 0.0)
    if name == "white":
        res["added"] = va / vb - 1
        res["added_theory"] = white_noise_added(detector, p, **settings)
    else:
        vt = vb - resid / n
        res["var_targeted"] = vt
        res["removed_of_targeted"] = (vb - va) / vt if vt > 0 else float("nan")
    return res


def _ratio(a, b):
    """Ratio estimator ``sum a / sum b`` and its delta-method standard error."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    k = a.size
    if b.sum() == 0:
        return float("nan"), float("nan")
    r = a.sum() / b.sum()
    se = np.sqrt(np.sum((a - r * b) ** 2) / (k * (k - 1))) / b.mean() if k > 1 else \
        float("nan")
    return float(r), float(se)


def pool_measurements(results):
    """Pool independent :func:`measure_reference_correction` runs (e.g. several seeds).

    Parameters
    ----------
    results : sequence of dict
        Runs with the same scheme, window, detector and number of frames.

    Returns
    -------
    dict
        Same layout, variances averaged over the runs and ratios recomputed from
        them (ratio estimators); each ratio ``x`` gets ``x_se``, its standard error
        from the run-to-run scatter (delta method; needs two runs or more).
    """
    results = list(results)
    if not results:
        raise ParameterError("'results' must hold at least one measurement, got none")
    keys = ("scheme", "side_window", "sigma", "nframes", "shape")
    for r in results[1:]:
        if any(r[k] != results[0][k] for k in keys):
            raise ParameterError(
                f"'results' must share {list(keys)}; got "
                f"{[tuple(x[k] for k in keys) for x in results]}")
    names = [n for n in results[0]["components"]
             if all(n in r["components"] for r in results)]
    pooled = {}
    for name in names:
        runs = [r["components"][name] for r in results]

        def col(key):
            return np.array([x[key] for x in runs])

        vb, va = col("var_before"), col("var_after")
        res = dict(var_before=float(vb.mean()), var_after=float(va.mean()))
        kept, se = _ratio(va, vb)
        res["removed"], res["removed_se"] = 1 - kept, se
        if "var_targeted" in runs[0]:
            vt = col("var_targeted")
            res["var_targeted"] = float(vt.mean())
            res["removed_of_targeted"], res["removed_of_targeted_se"] = _ratio(vb - va, vt)
        if "added" in runs[0]:
            res["added"], res["added_se"] = kept - 1, se
            res["added_theory"] = runs[0]["added_theory"]
        pooled[name] = res
    if "all" in pooled and "white" in pooled:
        a = [r["components"]["all"] for r in results]
        w = [r["components"]["white"] for r in results]
        num = [x["var_before"] - x["var_after"] for x in a]
        den = [x["var_before"] - y["var_before"] for x, y in zip(a, w)]
        (pooled["all"]["removed_of_correlated"],
         pooled["all"]["removed_of_correlated_se"]) = _ratio(num, den)
    out = {k: results[0][k] for k in keys}
    out.update(entropy=[r["entropy"] for r in results], runs=len(results),
               components=pooled)
    return out


def format_measurement(result):
    """Markdown table of a :func:`measure_reference_correction` result.

    Parameters
    ----------
    result : dict
        As returned by :func:`measure_reference_correction` or
        :func:`pool_measurements` (then ratios show ``+- standard error``).

    Returns
    -------
    str
        One row per component: CDS variance before and after (e-**2), fraction
        removed, targeted share of the variance, fraction of the targeted part
        removed, and for white noise the variance added (measured / closed form).
    """
    def fmt(r, key, spec):
        if key not in r:
            return ""
        s = format(r[key], spec)
        se = r.get(key + "_se")
        return s + (f" ± {se:.{spec[-2]}f}" if se is not None and np.isfinite(se) else "")

    lines = ["| component | var before (e-²) | var after (e-²) | removed | "
             "targeted share | removed of targeted | white added (meas. / theory) |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for name, r in result["components"].items():
        vb = r["var_before"]
        share = f"{r['var_targeted'] / vb:.3f}" if "var_targeted" in r and vb > 0 else ""
        add = ""
        if "added" in r:
            se = r.get("added_se")
            add = f"{r['added']:.2e}" + (f" ± {se:.1e}" if se is not None else "") + \
                f" / {r['added_theory']:.2e}"
        label = name
        if "removed_of_correlated" in r:
            corr = fmt(r, "removed_of_correlated", "+.3f")
            label += f" (correlated part removed: {corr})"
        lines.append(f"| {label} | {vb:.4g} | {r['var_after']:.4g} | "
                     f"{fmt(r, 'removed', '+.3f')} | {share} | "
                     f"{fmt(r, 'removed_of_targeted', '+.3f')} | {add} |")
    return "\n".join(lines)
