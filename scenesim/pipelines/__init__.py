"""The loop with the real pipelines: JWST Detector1 and romancal run on scenesim's files.

* :mod:`scenesim.pipelines.instrument`: the JWST identity of an exposure (scene table
  ``[instrument]``);
* :mod:`scenesim.pipelines.reffiles`: the calibration references of a simulated
  detector (gain, read noise, saturation, bias, linearity, dark, mask, IPC), known
  exactly because they are the engine's parameters;
* :mod:`scenesim.pipelines.jwst`: JWST uncal files through ``stdatamodels``, the
  references as JWST reference files, and ``calwebb_detector1`` run offline with them
  (optional ``jwst`` extra);
* :mod:`scenesim.pipelines.roman`: Roman Level 1 ASDF through ``roman_datamodels``,
  the references as Roman reference files, and romancal's ramp fitting offline
  (optional ``roman`` extra);
* :mod:`scenesim.pipelines.command`: ``scenesim pipeline jwst|roman``.

The pipelines' outputs (JWST ``rate`` files, Roman L2 files) are graded by
:func:`scenesim.validate.compare.compare_files`, like scenesim's own fits.  Importing
this package imports neither pipeline.
"""

__all__ = []
