"""What the detector does to collected charge, forward and inverse, and how it is read.

:mod:`~scenesim.detector.readout` (readout patterns and resultant times); the effects
on charge, each with its inverse where a pipeline needs one:
:mod:`~scenesim.detector.saturation`, :mod:`~scenesim.detector.nonlinearity`,
:mod:`~scenesim.detector.ipc` and :mod:`~scenesim.detector.flat`.  The ADC is
:mod:`noise.adc`.
"""

__all__ = []
