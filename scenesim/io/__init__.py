"""Files: the exposure (uncal), truth and slope files, written and read.

:mod:`~scenesim.io.exposure` (exposure and truth files, :class:`ExposureWriter`),
:mod:`~scenesim.io.fitfile` (slope files, ours and JWST rate files) and
:mod:`~scenesim.io.header` (the one header contract: every card written, and how it
is read back) and :mod:`~scenesim.io.cuberows` (an exposure's cube read by row blocks,
for a fit that never holds it).
"""

from scenesim.io.exposure import (Exposure, ExposureWriter, derived_path, read_exposure,
                                  read_exposure_header, read_truth, truth_path_for)
from scenesim.io.fitfile import FitResult, read_fit, read_slopes, write_fit
from scenesim.io.cuberows import CubeRows, exposure_rows, npy_rows

__all__ = ["Exposure", "ExposureWriter", "read_exposure", "read_truth", "truth_path_for",
           "derived_path", "read_exposure_header", "FitResult", "read_fit", "write_fit", "read_slopes",
           "CubeRows", "exposure_rows", "npy_rows"]
