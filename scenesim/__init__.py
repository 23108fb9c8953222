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

from noise.lazy import lazy_exports

#: Public name -> the module that defines it (imported on first use, so that
#: ``import scenesim`` is cheap and the command can install its signal handlers
#: before the heavy imports).
_EXPORTS = {
    "Readout": "scenesim.detector.readout",
    "NAMED_PATTERNS": "scenesim.detector.readout",
    "ROMAN_LIKE_TABLE": "scenesim.detector.readout",
    "Scene": "scenesim.scene",
    "load_scene": "scenesim.scene",
    "parse_scene": "scenesim.scene",
    "GaussianPSF": "scenesim.sky.psf",
    "AiryPSF": "scenesim.sky.psf",
    "ImagePSF": "scenesim.sky.psf",
    "render_point_sources": "scenesim.sky.psf",
    "encircled_energy": "scenesim.sky.psf",
    "LightCurve": "scenesim.sky.lightcurve",
    "ChargeEngine": "scenesim.engine",
    "EngineOptions": "scenesim.engine",
    "VariableSource": "scenesim.engine",
    "CosmicRayHits": "scenesim.engine",
    "Nonlinearity": "scenesim.detector.nonlinearity",
    "ipc_kernel": "scenesim.detector.ipc",
    "apply_ipc": "scenesim.detector.ipc",
    "write_exposure": "scenesim.run",
    "read_exposure": "scenesim.io.exposure",
    "read_truth": "scenesim.io.exposure",
    "correct_reference": "scenesim.calib.refpix",
    "measure_reference_correction": "scenesim.validate.refpix_study",
    "white_noise_added": "scenesim.validate.refpix_study",
    "fit_ramps": "scenesim.rampfit",
    "FitResult": "scenesim.io.fitfile",
    "read_fit": "scenesim.io.fitfile",
    "write_fit": "scenesim.io.fitfile",
    "optimal_variance": "scenesim.rampfit",
    "model_chi2": "scenesim.rampfit",
    "fit_exposure_file": "scenesim.calib.prepare",
    "prepare_exposure": "scenesim.calib.prepare",
    "PreparedExposure": "scenesim.calib.prepare",
    "PrepareOptions": "scenesim.calib.prepare",
    "Exposure": "scenesim.io.exposure",
    "Report": "scenesim.validate.compare",
    "compare": "scenesim.validate.compare",
    "compare_files": "scenesim.validate.compare",
    "build_engine": "scenesim.run",
    "run_scene": "scenesim.run",
    "check_budget": "scenesim.budget",
    "check_noise_budget": "scenesim.budget",
}

__all__ = list(_EXPORTS)


__getattr__, __dir__ = lazy_exports('scenesim', _EXPORTS, globals())
