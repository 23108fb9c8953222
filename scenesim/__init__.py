"""scenesim: HxRG scenes injected read by read into noise ramps, and their slope fits.

One subpackage per stage, one implementation of each physical step:

* :mod:`scenesim.scene`: scene files (TOML) validated into frozen dataclasses;
* :mod:`scenesim.sky`: what falls on the detector (rate maps, PSFs, light curves,
  catalogues, cosmic rays; :mod:`scenesim.sky.rates` builds the engine's input);
* :mod:`scenesim.detector`: the readout (patterns, resultant times) and each effect on
  charge with its inverse (saturation, nonlinearity, IPC, flat; the ADC is
  :mod:`noise.adc`, the clock :mod:`noise.clock`);
* :mod:`scenesim.engine`: charge read by read, at each pixel's own read time;
* :mod:`scenesim.run`: the orchestrator (engine -> files, then fit and compare);
* :mod:`scenesim.io`: the files (uncal exposure, truth, slopes) and the one header
  contract that writes and reads their cards;
* :mod:`scenesim.calib`: preparing an exposure for a fitter (reference pixels,
  saturation flags, linearisation, IPC undone, common mode, read noise);
* :mod:`scenesim.rampfit`: up-the-ramp fitting (CDS, OLS, optimal GLS, jumps);
* :mod:`scenesim.validate`: grading fits against the truth;
* :mod:`scenesim.adapters`: other libraries (stcal) run on our files;
* :mod:`scenesim.bench`: run time against the random-number floor.

The noise model lives in the sibling package :mod:`noise`.
"""

from scenesim.validate.compare import Report, compare, compare_files
from scenesim.detector.nonlinearity import Nonlinearity
from scenesim.detector.ipc import apply_ipc, ipc_kernel
from scenesim.engine import ChargeEngine, CosmicRayHits, EngineOptions, VariableSource
from scenesim.io.exposure import read_exposure, read_truth
from scenesim.io.exposure import Exposure
from scenesim.io.fitfile import FitResult, read_fit, write_fit
from scenesim.rampfit import fit_ramps, model_chi2, optimal_variance
from scenesim.calib.prepare import (PreparedExposure, PrepareOptions, fit_exposure_file,
                                    prepare_exposure)
from scenesim.sky.lightcurve import LightCurve
from scenesim.sky.psf import AiryPSF, GaussianPSF, ImagePSF, encircled_energy, render_point_sources
from scenesim.detector.readout import NAMED_PATTERNS, ROMAN_LIKE_TABLE, Readout
from scenesim.calib.refpix import correct_reference
from scenesim.validate.refpix_study import measure_reference_correction, white_noise_added
from scenesim.run import build_engine, run_scene, write_exposure
from scenesim.scene import Scene, load_scene, parse_scene

__all__ = [
    "Readout", "NAMED_PATTERNS", "ROMAN_LIKE_TABLE",
    "Scene", "load_scene", "parse_scene",
    "GaussianPSF", "AiryPSF", "ImagePSF", "render_point_sources", "encircled_energy",
    "LightCurve",
    "ChargeEngine", "EngineOptions", "VariableSource", "CosmicRayHits",
    "Nonlinearity", "ipc_kernel", "apply_ipc",
    "write_exposure", "read_exposure", "read_truth",
    "correct_reference", "measure_reference_correction", "white_noise_added",
    "fit_ramps", "FitResult", "read_fit", "write_fit",
    "optimal_variance", "model_chi2", "fit_exposure_file", "prepare_exposure",
    "PreparedExposure", "PrepareOptions", "Exposure",
    "Report", "compare", "compare_files",
    "build_engine", "run_scene",
]
