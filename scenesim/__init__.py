"""scenesim: HxRG scenes injected read by read into noise ramps, and their slope fits.

Modules, one per stage: :mod:`scenesim.detector.readout` (readout patterns),
:mod:`scenesim.scene` (TOML scene files), :mod:`scenesim.sky.psf`,
:mod:`scenesim.sky.sources`, :mod:`scenesim.sky.lightcurve`, :mod:`scenesim.sky.cosmic` (rates
and events), :mod:`scenesim.engine` (charge read by read), :mod:`scenesim.detector.effects`
(saturation, nonlinearity, IPC, flat, ADC), :mod:`scenesim.io.exposure` (uncal and truth
files), :mod:`scenesim.calib.refpix`, :mod:`scenesim.rampfit`, :mod:`scenesim.calib.prepare`
(reference correction and slopes), :mod:`scenesim.validate.compare` (fit vs truth),
:mod:`scenesim.run` (the orchestrator) and :mod:`scenesim.bench`;
:mod:`scenesim.adapters.stcal` runs the JWST library stcal's ramp fitting on our
exposures (optional ``[stcal]`` extra, imported only when used).
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
