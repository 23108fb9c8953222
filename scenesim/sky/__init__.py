"""What falls on the detector: rates (dark, background, point sources with PSFs and
light curves) and discrete events (cosmic rays)."""

__all__ = []
