"""Data-quality (DQ) bits of fitted pixels, and the variance of unmeasured pixels.

The bit values are those of the JWST pipeline (``jwst.datamodels.dqflags``), so that
scenesim slope files and JWST rate files can be graded by the same code:

==================  ==========  ====================================================
bit                 value       meaning in a scenesim slope file
==================  ==========  ====================================================
``DO_NOT_USE``      1           no slope could be measured (or a reference pixel)
``SATURATED``       2           at least one resultant of the pixel is saturated
``JUMP_DET``        4           at least one difference was flagged as a jump
``REFERENCE_PIXEL`` 2**31       reference pixel (always with ``DO_NOT_USE``)
==================  ==========  ====================================================

A pixel whose slope cannot be measured reports the finite, huge variance
:data:`BAD_VARIANCE` rather than NaN or infinity, so that inverse-variance weights
vanish without special cases.
"""

__all__ = ["DO_NOT_USE", "SATURATED", "JUMP_DET", "REFERENCE_PIXEL", "BAD_VARIANCE"]

#: DQ bits (JWST values).
DO_NOT_USE = 1
SATURATED = 2
JUMP_DET = 4
REFERENCE_PIXEL = 2 ** 31

#: Variance ((e-/s)^2) reported for unmeasured pixels: finite, huge, never NaN.
BAD_VARIANCE = 1e20
