"""What falls on the detector: rates and discrete events.

* :mod:`scenesim.sky.maps`: per-pixel maps (scalar or FITS image) and their loader.
* :mod:`scenesim.sky.tables`: the reader of catalogue and light-curve tables.
* :mod:`scenesim.sky.sources`: point-source catalogues and hot pixels.
* :mod:`scenesim.sky.psf`: PSFs and flux-conserving rendering of point sources.
* :mod:`scenesim.sky.lightcurve`: light curves with exact interval integrals.
* :mod:`scenesim.sky.cosmic`: cosmic-ray hits.
* :mod:`scenesim.sky.rates`: a scene's sky as the charge engine takes it.
"""

from scenesim.sky.cosmic import CosmicRayModel, draw_cosmic_rays
from scenesim.sky.lightcurve import LightCurve
from scenesim.sky.maps import FITS_EXTENSIONS, check_map_file, image_hdu, load_map
from scenesim.sky.psf import (AiryPSF, GaussianPSF, ImagePSF, encircled_energy,
                              render_point_sources)
from scenesim.sky.rates import cosmic_ray_hits, scene_rates
from scenesim.sky.sources import draw_hot_pixels, read_catalogue
from scenesim.sky.tables import TABLE_EXTENSIONS, column_values, find_columns, read_table

__all__ = [
    "CosmicRayModel", "draw_cosmic_rays",
    "LightCurve",
    "FITS_EXTENSIONS", "check_map_file", "image_hdu", "load_map",
    "AiryPSF", "GaussianPSF", "ImagePSF", "encircled_energy", "render_point_sources",
    "cosmic_ray_hits", "scene_rates",
    "draw_hot_pixels", "read_catalogue",
    "TABLE_EXTENSIONS", "column_values", "find_columns", "read_table",
]
