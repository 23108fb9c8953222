"""Adapters that run other libraries on scenesim's files.

:mod:`~scenesim.adapters.stcal` runs the JWST calibration library's ramp fitting
(stcal, an optional dependency imported only when a fit runs) on a scenesim exposure
prepared exactly as for scenesim's own fitters.
"""

from scenesim.adapters.stcal import STCAL_ALGORITHMS, fit_exposure_stcal, stcal_read_noise

__all__ = ["STCAL_ALGORITHMS", "fit_exposure_stcal", "stcal_read_noise"]
