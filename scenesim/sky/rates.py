"""A scene's sky, as the charge engine takes it: rates, variable sources, cosmic rays.

:func:`scene_rates` turns ``[sources]`` into

* the **static rate map**, e-/s per pixel of the read-out image: dark current +
  background (:func:`scenesim.sky.maps.load_map`) + hot pixels
  (:func:`scenesim.sky.sources.draw_hot_pixels`) + every constant point source
  rendered with the PSF (:func:`scenesim.sky.psf.render_point_sources`), all set to 0
  on the reference pixels, which collect no charge.  The light (background and
  sources, static or variable) is multiplied by the quantum-efficiency flat
  ``[effects] flat`` (:func:`scenesim.detector.flat.apply_flat`) before the engine
  draws its Poisson arrivals; dark current and hot pixels are not light and are not
  flat-fielded;
* the **variable sources**: one :class:`scenesim.engine.VariableSource` per star with
  a light curve (its rendered stamp at relative flux 1, and the
  :class:`~scenesim.sky.lightcurve.LightCurve` built once per light-curve name);
* the **rendered catalogue**: one row per star in the order of
  :meth:`scenesim.scene.SourcesConfig.star_table` (the inline stars, then the
  catalogue rows in the catalogue's order): the catalogue's ``id``, the ``info`` table
  of the rendering (flux on the array, flux lost outside the stamp, ...), the
  ``light_curve`` name and the catalogue's other columns; written to the truth file
  as ``SOURCES``, whose row numbers ``LCINTS.SOURCE`` gives (before, the constant
  stars came first and the catalogue's ``id`` and other columns were dropped).
  ``flux_on_array`` is the rate the array collects, the QE flat included (before, it
  left the flat out: a star on a flat of 0.5 was recorded at twice what its pixels
  collected).

and refuses, before any work, a pixel that would collect more than
:data:`scenesim.engine.MAX_CHARGE` in an integration (the variable sources at their
light curves' peak), naming what puts the charge there: the map file and pixel, the
catalogue file, row and ``id``, the inline star, the light curve and its peak.

:func:`cosmic_ray_hits` turns ``[effects] cosmic_ray_rate`` and
``cosmic_ray_charge`` into the engine's :class:`scenesim.engine.CosmicRayHits`
(:mod:`scenesim.sky.cosmic`).  The scene gives the log-normal charge by its median
``m`` and the sigma ``s`` of ln(charge); the model takes the mean
``m exp(s**2 / 2)`` and the standard deviation ``mean sqrt(exp(s**2) - 1)``.

Random streams (:mod:`noise.streams`), under the scene's seed: hot pixels draw from
``HOT_PIXELS`` ``(4,)``, cosmic rays from ``COSMIC_RAYS`` ``(3,)``, so switching one
on or off leaves the other draws unchanged.
"""

import warnings

import numpy as np
from astropy.table import vstack

from noise import streams
from noise.clock import exposure_slots
from noise.errors import ParameterError, ScenesimWarning

from scenesim.detector.flat import apply_flat
from scenesim.engine import MAX_CHARGE, CosmicRayHits, VariableSource
from scenesim.sky.cosmic import CosmicRayModel, draw_cosmic_rays
from scenesim.sky.maps import image_hdu, load_map
from scenesim.sky.psf import render_point_sources
from scenesim.sky.sources import draw_hot_pixels

__all__ = ["scene_rates", "cosmic_ray_hits", "hot_pixel_map", "integration_span",
           "SceneWarning"]

#: Stars named one by one in the warning about stars that miss the array.
_NAMED = 3


class SceneWarning(ScenesimWarning):
    """A scene that runs but probably not as meant: stars that put no charge on the
    array's collecting pixels (a catalogue wider than the array is normal; a lone
    star a million pixels away is more likely a unit slip)."""


def _seed(scene):
    if scene.seed is None:
        raise ParameterError("'seed' must be set before drawing a scene's sky; call "
                             "scene.ensure_seed()")
    return scene.seed


def hot_pixel_map(src, det, seed, refmask):
    """The extra dark rate (ny, nx) e-/s of the hot pixels of ``src`` (a scene's
    ``[sources]``) on ``det``, drawn under ``seed`` (:data:`noise.streams.HOT_PIXELS`)
    for its full array and cut (:func:`scenesim.sky.sources.draw_hot_pixels`): the
    one draw the engine and the pipelines' dark reference share."""
    return draw_hot_pixels(det.shape, src.hot_pixel_fraction, rate=src.hot_pixel_rate,
                           rng=streams.generator(seed, streams.HOT_PIXELS),
                           refmask=refmask, detector=det)


@np.errstate(over="ignore")    # an inf sum of huge maps is refused, named, below
def scene_rates(scene):
    """Static rate map, variable sources and rendered catalogue of ``scene``.

    Parameters
    ----------
    scene : scenesim.scene.Scene
        With ``seed`` set (hot pixels are drawn from it).

    Returns
    -------
    rate : ndarray, shape ``detector.shape``, float64, e-/s
        0 on the reference pixels.
    variable : list of scenesim.engine.VariableSource
        In star order (inline stars, then catalogue rows): the ``i``-th is the
        ``i``-th row of ``rendered`` with a ``light_curve``.
    rendered : astropy.table.Table or None
        One row per star, in star order, ``None`` without stars.
    """
    seed = _seed(scene)
    det = scene.detector
    src = scene.sources
    refmask = det.reference_mask()
    qe = None
    if scene.effects.flat != 1.0:
        qe = load_map(scene.effects.flat, det, name="flat")

    def light(r):
        """Photo-electrons: scaled by the QE flat (dark current is not)."""
        return r if qe is None else apply_flat(np.broadcast_to(r, det.shape), qe)

    dark = load_map(src.dark_current, det, name="dark_current")
    background = load_map(src.background, det, name="background")
    rate = dark + light(background)
    hot = 0.0
    if src.hot_pixel_fraction > 0:
        hot = hot_pixel_map(src, det, seed, refmask)
        rate = rate + hot
    stars = src.star_table()
    variable = []
    rendered = None
    psf = None
    if len(stars):
        psf = src.psf.build()
        static = np.asarray(stars["light_curve"]) == ""
        x, y, flux = (np.asarray(stars[k], dtype=np.float64) for k in ("x", "y", "flux"))
        rendered_parts = []
        if static.any():
            img, info = render_point_sources(
                det.shape, x[static], y[static], flux[static],
                psf, min_rate=src.psf.min_rate, blind=refmask, qe=qe)
            rate = rate + img                        # the QE flat is in (qe=)
            info["light_curve"] = [""] * len(info)
            rendered_parts.append(info)
        curves = {}
        for i in np.flatnonzero(~static):
            name = str(stars["light_curve"][i])
            if name not in curves:
                curves[name] = src.light_curve(name).build()
            img, info = render_point_sources(
                det.shape, [x[i]], [y[i]], [flux[i]], psf,
                min_rate=src.psf.min_rate, blind=refmask, qe=qe)
            idx = np.flatnonzero(img)
            variable.append(VariableSource(idx, img.ravel()[idx], curves[name]))
            info["light_curve"] = [name]
            rendered_parts.append(info)
        rendered = _in_star_order(vstack(rendered_parts), static, stars)
    rate = np.where(refmask, 0.0, rate)
    _check_charge(scene, rate, variable, {
        "dark": dark, "background": background, "qe": qe, "hot": hot, "stars": stars,
        "rendered": rendered, "psf": psf, "refmask": refmask})
    if rendered is not None:
        _warn_missed(rendered, det.shape)
    return rate, variable, rendered


def integration_span(detector, readout):
    """``(t_int, span)``: the length of one integration (s, its reset and read frames)
    and how the scene sets it, for messages."""
    t_int = exposure_slots(1, readout.nreads) * detector.frame_time
    span = (f"{readout.nreads + 1} frames of {detector.frame_time:.6g} s: [readout], and "
            f"[detector] 'dt' x (rows + 'nfoh') x (columns per output + 'nroh')")
    return t_int, span


def _check_charge(scene, rate, variable, parts):
    """Refuse, before any work, a pixel that would collect more than
    :data:`scenesim.engine.MAX_CHARGE` in one integration (its rate, the variable
    sources at their light curves' peak), naming what puts the charge there: the map
    file and its pixel, the catalogue file and row (and id), the inline star, the
    light curve.  (Before, the engine's check said only "'rate' ... is 1.97e+19 e-/s
    in the brightest pixel", the variable sources mentioned whether or not there were
    any.)"""
    det = scene.detector
    t_int, span = integration_span(det, scene.readout.build())
    peaks = [float(np.max(v.light_curve.flux)) for v in variable]
    # the static map's largest pixel, and the pixels the variable sources add to
    # at their peaks (no full-array copy: 134 MB on an H4RG)
    flat_rate = np.broadcast_to(rate, det.shape).reshape(-1)
    with np.errstate(over="ignore", invalid="ignore"):
        p = int(np.argmax(flat_rate)) if flat_rate.size else 0
        top = float(flat_rate[p]) if flat_rate.size else 0.0
        if variable:
            idx = np.concatenate([np.asarray(v.index).reshape(-1) for v in variable])
            add = np.concatenate([np.broadcast_to(np.asarray(v.weight, dtype=float)
                                                  * peak, np.shape(v.index)).reshape(-1)
                                  for v, peak in zip(variable, peaks)])
            pix, inv = np.unique(idx, return_inverse=True)
            vals = flat_rate[pix].astype(np.float64) + np.bincount(inv, weights=add,
                                                                   minlength=pix.size)
            k = int(np.argmax(vals)) if vals.size else -1   # (sources off the array)
            if k >= 0 and (vals[k] > top or not np.isfinite(vals[k])):
                top, p = float(vals[k]), int(pix[k])
        if top * t_int <= MAX_CHARGE:
            return
    y, x = divmod(p, det.nx)
    found = sorted(_contributions(scene, p, variable, peaks, parts),
                   key=lambda c: -c[1])
    where = f"pixel (x, y) = ({x}, {y}) of the read-out image"
    if found:
        (what, r), others = found[0], found[1:]
        head = f"{what} puts {r:.3g} e-/s on {where}"
        if others:
            listed = ", ".join(f"{v:.3g} e-/s from {w}" for w, v in others[:2])
            more = f" and {len(others) - 2} more" if len(others) > 2 else ""
            head += f" (which also gets {listed}{more}; {top:.3g} e-/s in all)"
    else:                                              # (not reached: a safeguard)
        head = f"{where} collects {top:.3g} e-/s"
    raise ParameterError(
        f"{head}, which would collect {top * t_int:.3g} e- over an integration of "
        f"{t_int:.6g} s ({span}); at most {MAX_CHARGE:.3g} e- (2**53) per pixel is "
        f"allowed")


def _at(value, p):
    """``value`` (a scalar or a map) at flat pixel ``p``."""
    return float(value) if np.ndim(value) == 0 else float(np.ravel(value)[p])


def _describe_value(table, key, value, at, det, p, unit, *, show=True):
    """A scene key as a message names it: ``[sources] 'dark_current' = 5.0 e-/s``, or
    for a map its file, with its value at pixel ``p`` if ``show`` and the file's
    pixel when the read-out window is cut from a full-array map."""
    if not isinstance(value, str):
        return f"{table} {key!r} = {value!r}{unit}"
    y, x = divmod(p, det.nx)
    _, shape = image_hdu(key, value)
    notes = [f"{at:.3g}{unit} at that pixel"] if show else []
    if tuple(shape) != det.shape:
        notes.append(f"file pixel (x, y) = ({x + det.x0}, {y + det.y0})")
    return f"{table} {key!r} map {value!r}" + (f" ({', '.join(notes)})" if notes else "")


def _contributions(scene, p, variable, peaks, parts):
    """``[(what, rate e-/s at flat pixel p)]`` of every source of charge there."""
    from scenesim.scene.schema import curve_table        # (imports this module)
    det, src, eff = scene.detector, scene.sources, scene.effects
    if parts["refmask"].ravel()[p]:
        return []
    qe = parts["qe"]
    q = 1.0 if qe is None else _at(qe, p)
    flat = "" if qe is None else \
        " x " + _describe_value("[effects]", "flat", eff.flat, q, det, p, "")
    out = []
    d = _at(parts["dark"], p)
    if d > 0:
        out.append((_describe_value("[sources]", "dark_current", src.dark_current, d,
                                    det, p, " e-/s", show=False), d))
    b = _at(parts["background"], p)
    if b * q > 0:
        out.append((_describe_value("[sources]", "background", src.background, b, det,
                                    p, " e-/s", show=qe is not None) + flat, b * q))
    h = _at(parts["hot"], p)
    if h > 0:
        out.append((f"a hot pixel ([sources] 'hot_pixel_rate' = {src.hot_pixel_rate!r} "
                    f"e-/s)", h))
    stars, rendered = parts["stars"], parts["rendered"]
    if rendered is None:
        return out
    n_inline = len(src.stars)

    curve_cache = {}

    def curve_cfg(cfg):
        if cfg.name not in curve_cache:
            curve_cache[cfg.name] = cfg.build().flux
        return curve_cache[cfg.name]

    def star(i):
        if i < n_inline:
            name = f"[[sources.stars]] #{i}"
        else:
            ident = stars["id"][i]
            ident = ident.item() if hasattr(ident, "item") else ident
            name = (f"[sources] catalogue {src.catalogue!r} row {i - n_inline} "
                    f"(id {ident!r})")
        name += f" 'flux' = {float(stars['flux'][i]):.6g} e-/s"
        curve = str(stars["light_curve"][i])
        if curve:
            cfg = src.light_curve(curve)
            name += f" x {curve_table(curve)} peak {float(np.max(curve_cfg(cfg))):.6g}"
            if cfg.kind == "file":
                name += f" (file {cfg.file!r})"
        return name + flat

    y, x = divmod(p, det.nx)
    lc = np.asarray(stars["light_curve"])
    ix = np.floor(np.asarray(rendered["x"], dtype=float) + 0.5)
    iy = np.floor(np.asarray(rendered["y"], dtype=float) + 0.5)
    radius = np.asarray(rendered["stamp_radius"])
    near = (np.abs(ix - x) <= radius) & (np.abs(iy - y) <= radius)
    for i in np.flatnonzero(near & (lc == "")):       # constant: render it alone
        img, _ = render_point_sources(
            det.shape, [rendered["x"][i]], [rendered["y"][i]], [rendered["flux"][i]],
            parts["psf"], min_rate=src.psf.min_rate, blind=parts["refmask"], qe=qe)
        if img.ravel()[p] > 0:
            out.append((star(int(i)), float(img.ravel()[p])))
    for i, v, peak in zip(np.flatnonzero(lc != ""), variable, peaks):
        w = v.weight[v.index == p]
        if w.size and w[0] > 0:
            out.append((star(int(i)), float(w[0]) * peak))
    return out


def _in_star_order(rendered, static, stars):
    """The rendering's rows (constant stars, then variable ones) back in the order of
    :meth:`~scenesim.scene.SourcesConfig.star_table` (inline stars, then the catalogue
    rows), with the star table's ``id`` first and its other columns (the catalogue's)
    last."""
    made = np.concatenate([np.flatnonzero(static), np.flatnonzero(~static)])
    rendered = rendered[np.argsort(made, kind="stable")]
    if "id" in stars.colnames:
        rendered.add_column(stars["id"], index=0, name="id")
    for name in stars.colnames:
        if name not in rendered.colnames:
            rendered[name] = stars[name]
    return rendered


def _warn_missed(rendered, shape):
    """A :class:`SceneWarning` naming the stars whose PSF puts nothing on the
    collecting pixels (``frac_on_array`` 0: the stamp misses the array, or covers only
    reference pixels); the truth catalogue keeps them, with ``flux_on_array`` 0."""
    missed = np.flatnonzero(np.asarray(rendered["frac_on_array"]) <= 0)
    if not missed.size:
        return
    ny, nx = shape
    named = ", ".join(f"({rendered['x'][i]:.6g}, {rendered['y'][i]:.6g})"
                      for i in missed[:_NAMED])
    more = f" and {missed.size - _NAMED} more" if missed.size > _NAMED else ""
    warnings.warn(
        f"{missed.size} of {len(rendered)} stars put no charge on the array's "
        f"collecting pixels, at (x, y) = {named}{more} (the array spans "
        f"-0.5 to {nx - 0.5:g} in x and -0.5 to {ny - 0.5:g} in y, pixel centres at "
        f"integers); they are kept "
        f"in the truth catalogue with flux_on_array = 0", SceneWarning, stacklevel=3)


def cosmic_ray_hits(scene, t_total):
    """The cosmic-ray deposits of ``scene`` over ``[0, t_total)``.

    Parameters
    ----------
    scene : scenesim.scene.Scene
        With ``seed`` set.
    t_total : float
        Length of the exposure, s (every integration's reset and read frames).

    Returns
    -------
    scenesim.engine.CosmicRayHits or None
        ``None`` when ``cosmic_ray_rate`` is 0.
    """
    eff = scene.effects
    if eff.cosmic_ray_rate <= 0:
        return None
    seed = _seed(scene)
    det = scene.detector
    median, sigma_ln = eff.cosmic_ray_charge
    try:
        with np.errstate(over="raise"):
            mean = median * np.exp(sigma_ln ** 2 / 2)
            model = CosmicRayModel(rate=eff.cosmic_ray_rate, charge_mean=mean,
                                   charge_sigma=mean * np.sqrt(np.expm1(sigma_ln ** 2)))
    except (ParameterError, FloatingPointError) as exc:
        raise ParameterError(
            f"[effects] 'cosmic_ray_charge' = {list(eff.cosmic_ray_charge)!r} "
            f"([median_e, sigma_ln]) gives no finite log-normal charge per hit: "
            f"{exc}") from exc
    try:
        table = draw_cosmic_rays(model, det.shape, det.pixel_pitch, 0.0, t_total,
                                 rng=streams.generator(seed, streams.COSMIC_RAYS),
                                 refmask=det.reference_mask())
    except ParameterError as exc:
        raise ParameterError(f"[effects] 'cosmic_ray_rate': {exc}") from exc
    index = np.asarray(table["Y"], dtype=np.int64) * det.nx + np.asarray(table["X"],
                                                                          dtype=np.int64)
    return CosmicRayHits(np.asarray(table["TIME"], dtype=float), index,
                         np.asarray(table["CHARGE"], dtype=float))
