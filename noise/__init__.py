"""HxRG noise generator: empty ramps from Rauscher (2015, PASP 127, 1144), streamed.

Public API
----------
Detector, Subarray, PRESETS, preset
    Geometry and the one clock (pixel read times, frame time).
NoiseParams, NIRSPEC_DEFAULTS, ZERO_NOISE
    Amplitudes (e-, read noise per read) with a length-independent definition.
NoiseGenerator
    Frame-by-frame generator (``frames``), ``cube`` convenience.
write_noise_fits
    Stream a ramp to FITS (float32 e- or uint16 DN), atomically.
"""

from noise.clock import PRESETS, Detector, Subarray, preset
from noise.errors import FileFormatError, ParameterError, ScenesimError
from noise.adc import ADC, from_dn, to_dn
from noise.fitsio import atomic_path, package_version, write_noise_fits
from noise.generator import Layout, NoiseGenerator
from noise.streams import NOISE_COMPONENTS, root_seed
from noise.params import NIRSPEC_DEFAULTS, ZERO_NOISE, NoiseParams
from noise.pink import (PinkSeries, measure_psd_error, pink_psd_shape, realised_psd,
                   unit_frame_variance)
from noise.template import synthetic_template, template_for

__all__ = [
    "Detector", "Subarray", "PRESETS", "preset",
    "NoiseParams", "NIRSPEC_DEFAULTS", "ZERO_NOISE",
    "NoiseGenerator", "Layout", "NOISE_COMPONENTS", "root_seed",
    "write_noise_fits", "atomic_path", "package_version", "ADC", "to_dn", "from_dn",
    "PinkSeries", "pink_psd_shape", "realised_psd", "unit_frame_variance",
    "measure_psd_error",
    "synthetic_template", "template_for",
    "ScenesimError", "ParameterError", "FileFormatError",
]
