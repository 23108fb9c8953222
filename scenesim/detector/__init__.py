"""What the detector does to collected charge, forward and inverse, and how it is read.

:mod:`~scenesim.detector.readout` (readout patterns and resultant times); the effects
on charge, each with its inverse where a pipeline needs one:
:mod:`~scenesim.detector.saturation`, :mod:`~scenesim.detector.nonlinearity`,
:mod:`~scenesim.detector.ipc` and :mod:`~scenesim.detector.flat`.  The ADC is
:mod:`noise.adc`.
"""

from scenesim.detector.dq import BAD_VARIANCE, DO_NOT_USE, JUMP_DET, REFERENCE_PIXEL, SATURATED
from scenesim.detector.flat import apply_flat
from scenesim.detector.ipc import apply_ipc, ipc_kernel, ipc_noise_gain, undo_ipc
from scenesim.detector.nonlinearity import Nonlinearity, linearize_resultants
from scenesim.detector.readout import (NAMED_PATTERNS, ROMAN_LIKE_SKIP_TABLE,
                                       ROMAN_LIKE_TABLE, Readout)
from scenesim.detector.saturation import FullWell, apply_saturation

__all__ = ["Readout", "NAMED_PATTERNS", "ROMAN_LIKE_TABLE", "ROMAN_LIKE_SKIP_TABLE",
           "FullWell", "apply_saturation", "Nonlinearity", "linearize_resultants",
           "ipc_kernel", "apply_ipc", "undo_ipc", "ipc_noise_gain", "apply_flat",
           "DO_NOT_USE", "SATURATED", "JUMP_DET", "REFERENCE_PIXEL", "BAD_VARIANCE"]
