"""scenesim: HxRG scenes injected read by read into noise ramps, and their slope fits.

Modules, one per stage: :mod:`scenesim.readout` (readout patterns),
:mod:`scenesim.scene` (TOML scene files), :mod:`scenesim.psf`,
:mod:`scenesim.sources`, :mod:`scenesim.lightcurve`, :mod:`scenesim.cosmic` (rates
and events), :mod:`scenesim.engine` (charge read by read), :mod:`scenesim.effects`
(saturation, nonlinearity, IPC, flat, ADC), :mod:`scenesim.exposure` (uncal and truth
files), :mod:`scenesim.refpix`, :mod:`scenesim.fit`, :mod:`scenesim.fitting`
(reference correction and slopes), :mod:`scenesim.compare` (fit vs truth),
:mod:`scenesim.run` (the orchestrator) and :mod:`scenesim.bench`;
:mod:`scenesim.stcal_adapter` runs the JWST library stcal's ramp fitting on our
exposures (optional ``[stcal]`` extra, imported only when used).
The noise model lives in the sibling package :mod:`noise`.
"""

from .compare import Report, compare, compare_files
from .effects import Nonlinearity, apply_ipc, ipc_kernel
from .engine import ChargeEngine, CosmicRayHits, EngineOptions, VariableSource
from .exposure import read_exposure, read_truth, write_exposure
from .exposure import Exposure
from .fit import FitResult, fit_ramps, model_chi2, optimal_variance, read_fit, write_fit
from .fitting import PreparedExposure, fit_exposure_file, prepare_exposure
from .lightcurve import LightCurve
from .psf import AiryPSF, GaussianPSF, ImagePSF, encircled_energy, render_point_sources
from .readout import NAMED_PATTERNS, ROMAN_LIKE_TABLE, Readout
from .refpix import correct_reference, measure_reference_correction, white_noise_added
from .run import build_engine, run_scene
from .scene import Scene, load_scene, parse_scene

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
    "PreparedExposure", "Exposure",
    "Report", "compare", "compare_files",
    "build_engine", "run_scene",
]
