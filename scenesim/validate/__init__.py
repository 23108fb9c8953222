"""Grading fits against the injected truth: statistics, photometry and plots.

:func:`compare` (:mod:`~scenesim.validate.compare`) assembles the report from
:mod:`~scenesim.validate.stats` (per true-rate bin), :mod:`~scenesim.validate.jumps`,
:mod:`~scenesim.validate.photometry` and :mod:`~scenesim.validate.plots`;
:mod:`~scenesim.validate.refpix_study` measures what reference-pixel corrections
remove from each noise component.
"""

from scenesim.validate.compare import DEFAULT_EDGES, Report, compare, compare_files

__all__ = ["Report", "compare", "compare_files", "DEFAULT_EDGES"]
