"""Level-1 preparation of an exposure before fitting.

:mod:`~scenesim.calib.prepare` runs the steps in order (:class:`PrepareOptions`
chooses them): DN to e-, IPC undone (:func:`scenesim.detector.ipc.undo_ipc`),
saturation flags (:mod:`~scenesim.calib.saturation`), the reference-pixel correction
(:mod:`~scenesim.calib.refpix`), the linearisation
(:func:`scenesim.detector.nonlinearity.linearize_resultants`), and the noise model
measured from the data, common mode and effective read noise
(:mod:`~scenesim.calib.noise_model`).  Read noise is per read, in e- (not CDS).
"""

from scenesim.calib.noise_model import NOISE_MIN_PIXELS, common_mode, measure_read_noise
from scenesim.calib.prepare import (PreparedExposure, PrepareOptions, fit_exposure_file,
                                    load_exposure, prepare_exposure)
from scenesim.calib.refpix import SCHEMES, correct_reference, reference_layout
from scenesim.calib.saturation import SaturationOptions, saturation_flags

__all__ = ["PrepareOptions", "PreparedExposure", "prepare_exposure", "load_exposure",
           "fit_exposure_file", "SaturationOptions", "saturation_flags", "SCHEMES",
           "correct_reference", "reference_layout", "NOISE_MIN_PIXELS", "common_mode",
           "measure_read_noise"]
