"""What the detector does to collected charge, forward and inverse, and how it is read.

:mod:`~scenesim.detector.readout` (readout patterns and resultant times) and
:mod:`~scenesim.detector.effects` (saturation, nonlinearity, IPC, flat).
"""

__all__ = []
