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
  stars came first and the catalogue's ``id`` and other columns were dropped).  ``flux_on_array`` is the rate
  the array collects, the QE flat included (before, it left the flat out: a star on
  a flat of 0.5 was recorded at twice what its pixels collected).

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
from noise.errors import ParameterError, ScenesimWarning

from scenesim.detector.flat import apply_flat
from scenesim.engine import CosmicRayHits, VariableSource
from scenesim.sky.cosmic import CosmicRayModel, draw_cosmic_rays
from scenesim.sky.maps import load_map
from scenesim.sky.psf import render_point_sources
from scenesim.sky.sources import draw_hot_pixels

__all__ = ["scene_rates", "cosmic_ray_hits", "SceneWarning"]

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

    rate = load_map(src.dark_current, det, name="dark_current")
    rate = rate + light(load_map(src.background, det, name="background"))
    if src.hot_pixel_fraction > 0:
        rate = rate + draw_hot_pixels(det.shape, src.hot_pixel_fraction,
                                      rate=src.hot_pixel_rate,
                                      rng=streams.generator(seed, streams.HOT_PIXELS),
                                      refmask=refmask)
    stars = src.star_table()
    variable = []
    rendered = None
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
        _warn_missed(rendered, det.shape)
    rate = np.where(refmask, 0.0, rate)
    return rate, variable, rendered


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
