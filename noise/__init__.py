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

from noise.lazy import lazy_exports

#: Public name -> the module that defines it (imported on first use, so that
#: ``import noise`` is cheap and the command can install its signal handlers
#: before the heavy imports).
_EXPORTS = {
    "Detector": "noise.clock",
    "Subarray": "noise.clock",
    "PRESETS": "noise.clock",
    "preset": "noise.clock",
    "NoiseParams": "noise.params",
    "NIRSPEC_DEFAULTS": "noise.params",
    "ZERO_NOISE": "noise.params",
    "NoiseGenerator": "noise.generator",
    "Layout": "noise.generator",
    "NOISE_COMPONENTS": "noise.streams",
    "root_seed": "noise.streams",
    "write_noise_fits": "noise.fitsio",
    "atomic_path": "noise.fitsio",
    "package_version": "noise.fitsio",
    "ADC": "noise.adc",
    "to_dn": "noise.adc",
    "from_dn": "noise.adc",
    "PinkSeries": "noise.pink",
    "pink_psd_shape": "noise.pink",
    "realised_psd": "noise.pink",
    "unit_frame_variance": "noise.pink",
    "measure_psd_error": "noise.pink",
    "synthetic_template": "noise.template",
    "template_for": "noise.template",
    "ScenesimError": "noise.errors",
    "ParameterError": "noise.errors",
    "ParameterTypeError": "noise.errors",
    "FileFormatError": "noise.errors",
}

__all__ = list(_EXPORTS)


__getattr__, __dir__ = lazy_exports('noise', _EXPORTS, globals())
